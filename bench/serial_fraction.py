#!/usr/bin/env python3
"""Serial fraction of a two-thread fitting_bench run from perf samples (bench/README.md,
issue 15 ninth round): wall-clock speed-ups need a quiet machine, CPU samples do not.

  perf record -F 2999 --call-graph dwarf,16384 -o run.data build/bench/fitting_bench \
      --mesh=/tmp/kern/gmsh_L9.obj --benchmark_filter='BM_FitQuantities/deg:2/threads:2/' --benchmark_min_time=3
  bench/serial_fraction.py run.data [BM_FitQuantities]

Each cpu-clock sample after the benchmark's first one is classed by thread and stack:
serial   the main thread outside an OpenMP region (no ParallelFor frame),
parallel inside one, on either thread, not waiting (stacks that unwinding cuts short
         inside the AVX-512 kernels count here: the serial code's stacks unwind),
idle     libgomp's spin and barrier waits (no symbols: '[unknown]' leaves), left out.
Prints s = serial / (serial + parallel), the Amdahl bound 1 / (s + (1 - s) / 2) and
where the serial and idle samples are.
"""
import collections
import re
import subprocess
import sys


def read_samples(path):
    out = subprocess.run(['perf', 'script', '-i', path, '-F', 'tid,ip,sym', '--no-inline'],
                         capture_output=True, text=True, check=True).stdout
    samples, cur = [], None
    for line in out.split('\n'):
        if not line.strip():
            if cur:
                samples.append(cur)
            cur = None
        elif not line.startswith('\t'):
            cur = (int(line.split()[0]), [])
        elif cur is not None:
            parts = line.split(None, 1)
            cur[1].append(re.sub(r'\+0x[0-9a-f]+.*', '', parts[1] if len(parts) > 1 else '?'))
    if cur:
        samples.append(cur)
    return samples


def main():
    samples = read_samples(sys.argv[1])
    bench = sys.argv[2] if len(sys.argv) > 2 else 'BM_FitQuantities'
    main_tid = samples[0][0]
    started = False
    cats, serial_by, idle_by = collections.Counter(), collections.Counter(), collections.Counter()
    for tid, st in samples:
        joined = ' '.join(st)
        if not started:
            started = tid == main_tid and bench in joined
            if not started:
                continue
        ours = [x for x in st if 'geomfit' in x or 'Eigen' in x or 'std::' in x or 'mem' in x]
        leaf = st[0] if st else '?'
        if tid != main_tid:
            cat = 'parallel' if ours else 'idle'
            if cat == 'idle':
                idle_by['worker ' + leaf[:60]] += 1
        elif leaf == '[unknown]' and 'MakePointRecords' not in joined:
            cat = 'idle'  # libgomp, in a ParallelFor that may be inlined into its caller
            idle_by['main libgomp'] += 1
        elif 'benchmark::' not in joined or 'ParallelFor' in joined:
            cat = 'parallel'
        else:
            cat = 'serial'
            serial_by[' < '.join(x[:60] for x in [leaf] + ours[:3])] += 1
        cats[cat] += 1
    work = cats['serial'] + cats['parallel']
    s = cats['serial'] / work
    print(dict(cats), 'serial fraction s = %.4f' % s, 'Amdahl 2-thread bound = %.3fx' % (1 / (s + (1 - s) / 2)))
    print('--- serial (main thread outside OpenMP) ---')
    for k, v in serial_by.most_common(20):
        print('%6d %5.2f%%  %s' % (v, 100 * v / work, k))
    print('--- idle ---')
    for k, v in idle_by.most_common(6):
        print('%6d  %s' % (v, k))


if __name__ == '__main__':
    main()
