#!/usr/bin/python3
"""The whole `geomfit curvature --local` process against CGAL's whole process (issue 15,
item 4 and its check "whole process >= 20x at degree 2, >= 40x at degree 4"), in the three
protocols that give different figures on a VM whose host takes freed memory back
(bench/README.md, "Issue 15, seventh round: page faults of the whole process"):

  back      geomfit runs back to back (its heap pages are warm);
  alt       each geomfit run follows a CGAL run (CGAL's freed memory is what it gets);
  pause     a pause of --pause seconds before each geomfit run (the host has taken the
            free memory back: the cold case).

CPU time of each child (user + system, from wait4: what `perf stat -e task-clock` counts)
is collected; the script prints medians, min-max and the ratio of CGAL's median to each
protocol's median, with the machine and load average. Several geomfit builds may be given
(for example main's and a branch's): their runs are interleaved, so they share each window.

  /usr/bin/python3 bench/whole_process.py --mesh /tmp/kern/gmsh_L9.obj --degree 2 \
      --geomfit build/clients/cpp/geomfit [--geomfit other/geomfit] \
      --cgal build/bench/cgal_whole_process [--runs 9] [--cgal-runs 5] [--pause 3]

Exit status 1 if a child fails, or (with --check) if the outputs of the geomfit builds
differ byte for byte (they should be equal for any change that keeps the bits).
"""
import argparse
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time


def cpu_ms(cmd):
    """Runs cmd; returns its user + system CPU time in ms (raises on failure)."""
    with open(os.devnull, 'wb') as null:
        proc = subprocess.Popen(cmd, stdout=null, stderr=subprocess.PIPE)
        _, status, usage = os.wait4(proc.pid, 0)
        err = proc.stderr.read().decode(errors='replace')
        proc.stderr.close()
    if os.waitstatus_to_exitcode(status) != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed: {err.strip()}")
    return 1e3 * (usage.ru_utime + usage.ru_stime)


def machine():
    model = '?'
    try:
        for line in open('/proc/cpuinfo'):
            if line.startswith('model name'):
                model = line.split(':', 1)[1].strip()
                break
    except OSError:
        pass
    return f"{model}, {os.cpu_count()} cpus, {platform.system()} {platform.release()}"


def summary(xs):
    return f"{statistics.median(xs):8.1f} ({min(xs):.1f}-{max(xs):.1f})"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument('--mesh', required=True)
    ap.add_argument('--degree', type=int, default=2)
    ap.add_argument('--threads', type=int, default=1)
    ap.add_argument('--geomfit', action='append', required=True, help='a geomfit binary (repeatable)')
    ap.add_argument('--cgal', required=True, help='bench/cgal_whole_process')
    ap.add_argument('--runs', type=int, default=9, help='runs per geomfit build and protocol')
    ap.add_argument('--cgal-runs', type=int, default=5, help='CGAL runs in the back-to-back window')
    ap.add_argument('--pause', type=float, default=3.0, help='seconds before each run of "pause"')
    ap.add_argument('--protocols', default='back,alt,pause')
    ap.add_argument('--check', action='store_true', help='the builds\' .npy outputs must be equal')
    a = ap.parse_args()

    tmp = tempfile.mkdtemp(prefix='whole_process.')
    def gf(i):
        return [a.geomfit[i], 'curvature', '--local', a.mesh, '--degree', str(a.degree),
                '--threads', str(a.threads), '--output', os.path.join(tmp, f'out{i}.npy')]
    cgal = [a.cgal, a.mesh, str(a.degree), os.path.join(tmp, 'cgal.bin')]
    protocols = a.protocols.split(',')
    times = {(p, i): [] for p in protocols for i in range(len(a.geomfit))}
    cgal_times = []

    print(f"machine: {machine()}; load before: {os.getloadavg()[0]:.2f}")
    print(f"mesh {a.mesh}, degree {a.degree}, {a.threads} thread(s), {a.runs} runs per build and protocol")
    for i in range(len(a.geomfit)):  # warm the page cache and the binaries
        cpu_ms(gf(i))
    for r in range(a.runs):
        order = list(range(len(a.geomfit)))
        order = order[r % len(order):] + order[:r % len(order)]  # rotate who goes first
        if 'back' in protocols:
            for i in order:
                times[('back', i)].append(cpu_ms(gf(i)))
        if 'alt' in protocols:
            for i in order:
                cgal_times.append(cpu_ms(cgal))
                times[('alt', i)].append(cpu_ms(gf(i)))
        if 'pause' in protocols:
            for i in order:
                time.sleep(a.pause)
                times[('pause', i)].append(cpu_ms(gf(i)))
    while len(cgal_times) < a.cgal_runs:
        cgal_times.append(cpu_ms(cgal))

    c = statistics.median(cgal_times)
    print(f"load after: {os.getloadavg()[0]:.2f}")
    print(f"CGAL whole process: median (min-max) {summary(cgal_times)} ms, {len(cgal_times)} runs")
    print(f"{'protocol':8s} {'build':40s} {'median (min-max) ms':>26s} {'x CGAL':>8s} {'worst run':>9s}")
    for p in protocols:
        for i, b in enumerate(a.geomfit):
            xs = times[(p, i)]
            print(f"{p:8s} {b[-40:]:40s} {summary(xs):>26s} {c / statistics.median(xs):7.1f}x "
                  f"{c / max(xs):8.1f}x")
    status = 0
    if a.check and len(a.geomfit) > 1:
        ref = open(os.path.join(tmp, 'out0.npy'), 'rb').read()
        for i in range(1, len(a.geomfit)):
            same = open(os.path.join(tmp, f'out{i}.npy'), 'rb').read() == ref
            print(f"output of build {i} {'equals' if same else 'DIFFERS FROM'} build 0's")
            status |= 0 if same else 1
    return status


if __name__ == '__main__':
    try:
        sys.exit(main())
    except RuntimeError as e:
        print(e, file=sys.stderr)
        sys.exit(1)
