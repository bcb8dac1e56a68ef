#!/usr/bin/python3
"""Python client against a real geomfit-server, and the same against the C++ client.

Times, per mesh size (tori of 1k, 10k and 100k vertices):
  curvature  ComputeDifferentials on cached fits and quantities (all transport);
  update     UpdatePositions alone;
  fsi step   UpdatePositions + ComputeDifferentials (a new revision each step);
             "fsi server compute" is the compute the step used on the server (the
             summary's fit_ms + evaluate_ms, or joined_compute_ms when the request
             joined the prefetch) and "fsi overhead" the step minus it, per step;
             "fsi compute" is BM_InProcessFsiCompute (in process, for reference).

With --cpp-bench (build/bench/service/service_rpc_bench) the C++ client is timed against
the same server process, in rounds interleaved with the Python rounds so that a
drifting machine affects both alike; the last columns give Python's overhead over C++'s.
The Python client is timed with each --transport (update_positions and curvature through
the C++ client, geomfit._native, or through grpcio), one column each.

    PYTHONPATH=clients/python:build/python /usr/bin/python3 bench/python_client_bench.py \\
        build/server/geomfit-server --cpp-bench build/bench/service/service_rpc_bench \\
        [--transport native|grpcio|both] [--store memory|sqlite] [--rounds 5] [--reps 20] [--threads 1]
"""
import argparse
import contextlib
import json
import os
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "clients", "python"))
import geomfit  # noqa: E402

SIZES = (1000, 10000, 100000)
FSI_SIZES = (1000, 10000)


def torus(vertices, R=1.0, r=0.3):
    """The torus of GenerateTorusMesh's grid (3m x m vertices) without its jitter."""
    m = max(4, int(round(np.sqrt(vertices / 3.0))))
    n = 3 * m
    u = 2 * np.pi * np.arange(n) / n
    v = 2 * np.pi * np.arange(m) / m
    U, V = np.meshgrid(u, v, indexing="ij")
    pos = np.stack([(R + r * np.cos(V)) * np.cos(U), (R + r * np.cos(V)) * np.sin(U), r * np.sin(V)], -1)
    idx = np.arange(n * m).reshape(n, m)
    a, b = idx, np.roll(idx, -1, axis=0)
    c, d = np.roll(b, -1, axis=1), np.roll(a, -1, axis=1)
    tris = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return pos.reshape(-1, 3), tris.astype(np.int32)


def timed(fn, reps, min_time):
    """Median milliseconds of fn(k) over a loop of at least `reps` calls and `min_time`
    seconds, after a few untimed calls: what the C++ rounds report as p50_ms (medians,
    as this VM stalls a thread for milliseconds now and then)."""
    for k in range(3):
        fn(k)
    ms, start = [], time.perf_counter()
    while len(ms) < reps or time.perf_counter() - start < min_time:
        a = time.perf_counter()
        fn(len(ms))
        ms.append(1e3 * (time.perf_counter() - a))
    return statistics.median(ms)


def python_round(client, meshes, reps, min_time):
    """One round of Python timings: {(what, n): ms}."""
    out = {}
    for n, (pos, mesh_id, update_id) in meshes.items():
        # Two position sets in turn, the states service_rpc_bench's positions alternate
        # between (it moves x by +-1e-4 in place each step).
        moves = (pos + [1e-4, 0, 0], pos)
        client.curvature(mesh_id)  # fits and quantities cached
        out[("curvature", n)] = timed(lambda k: client.curvature(mesh_id), reps, min_time)
        # Updates alone on a mesh nobody asked differentials of (no prefetch after them),
        # as BM_FsiUpdatePositionsOnly does.
        out[("update", n)] = timed(lambda k: client.update_positions(update_id, moves[k % 2]), reps, min_time)
        if n in FSI_SIZES:
            compute, overhead = [], []

            def step(k):
                a = time.perf_counter()
                info = client.update_positions(mesh_id, moves[k % 2])
                s = client.curvature(mesh_id, revision=info.revision).summary
                compute.append(s.fit_ms + s.evaluate_ms + s.joined_compute_ms)
                overhead.append(1e3 * (time.perf_counter() - a) - compute[-1])
            out[("fsi step", n)] = timed(step, max(3, reps // 2), min_time)
            out[("fsi server compute", n)] = statistics.median(compute)
            out[("fsi overhead", n)] = statistics.median(overhead)
    return out


def cpp_round(cpp_bench, target, threads, min_time):
    """One round of the C++ client (service_rpc_bench against `target`)."""
    env = dict(os.environ, GEOMFIT_BENCH_TARGET=target, GEOMFIT_BENCH_THREADS=str(threads))
    res = subprocess.run([cpp_bench, "--benchmark_filter=BM_(RpcCurvatureCachedFits|FsiStep|FsiUpdatePositionsOnly|InProcessFsiCompute)/",
                          "--benchmark_min_time=%g" % min_time, "--benchmark_format=json"],
                         env=env, capture_output=True, text=True, check=True)
    out = {}
    for b in json.loads(res.stdout)["benchmarks"]:
        name, n = b["run_name"].split("/")[:2]
        n = int(n)
        if name == "BM_RpcCurvatureCachedFits":
            out[("curvature", n)] = b["p50_ms"]
        elif name == "BM_FsiUpdatePositionsOnly":
            out[("update", n)] = b["p50_ms"]
        elif name == "BM_FsiStep":
            out[("fsi step", n)] = b["p50_ms"]
            out[("fsi server compute", n)] = b["server_compute_ms"]
            out[("fsi overhead", n)] = b["overhead_p50_ms"]
        elif name == "BM_InProcessFsiCompute":
            out[("compute", n)] = b["real_time"]
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("server_binary")
    ap.add_argument("--cpp-bench", help="service_rpc_bench, to time the C++ client against the same server")
    ap.add_argument("--transport", default="both", choices=["native", "grpcio", "both"],
                    help="the Python client's transport(s) to time")
    ap.add_argument("--store", default="memory", choices=["memory", "sqlite"])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--reps", type=int, default=20, help="least Python calls per quantity per round")
    ap.add_argument("--min-time", type=float, default=0.3,
                    help="least seconds per quantity per round, for both clients (each reports its mean)")
    ap.add_argument("--threads", type=int, default=1,
                    help="server --threads (numeric threads per computation)")
    args = ap.parse_args()
    transports = ["native", "grpcio"] if args.transport == "both" else [args.transport]
    with tempfile.TemporaryDirectory(prefix="geomfit_pybench_") as data_dir:
        proc = subprocess.Popen([args.server_binary, "--host=127.0.0.1", "--port=0", "--log-level=error",
                                 "--store=" + args.store, "--data-dir=" + data_dir,
                                 "--threads=%d" % args.threads],
                                stdout=subprocess.PIPE, text=True)
        try:
            target = "127.0.0.1:" + re.search(r"port (\d+)", proc.stdout.readline()).group(1)
            py, cpp = {t: {} for t in transports}, {}
            with contextlib.ExitStack() as stack:
                clients = {t: stack.enter_context(geomfit.Client(target, transport=t)) for t in transports}
                meshes = {}
                for n in SIZES:
                    pos, tris = torus(n)
                    first = clients[transports[0]]
                    meshes[n] = (pos, first.upload(pos, tris, name="bench").mesh_id,
                                 first.upload(pos, tris, name="bench-update").mesh_id)
                for r in range(args.rounds):
                    for t in transports if r % 2 == 0 else transports[::-1]:  # neither always first
                        for k, v in python_round(clients[t], meshes, args.reps, args.min_time).items():
                            py[t].setdefault(k, []).append(v)
                    if args.cpp_bench:
                        for k, v in cpp_round(args.cpp_bench, target, args.threads, args.min_time).items():
                            cpp.setdefault(k, []).append(v)
                    print("round %d/%d done" % (r + 1, args.rounds), file=sys.stderr)
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(timeout=30)
    print("median over %d rounds of each round's median, ms (store %s, server --threads=%d)"
          % (args.rounds, args.store, args.threads))
    # rows[key] = [Python ms per transport..., C++ ms]
    columns = ["py " + t for t in transports]
    print(("%-19s %8s" + " %10s" * (2 * len(columns) + 1))
          % ("what", "vertices", *columns, "c++", *[c + " / c++" for c in columns]))
    rows = {k: [statistics.median(py[t][k]) for t in transports]
            + [statistics.median(cpp[k]) if k in cpp else float("nan")] for k in py[transports[0]]}
    for n in FSI_SIZES:
        if ("compute", n) in cpp:  # in-process, for reference
            rows[("fsi compute", n)] = [statistics.median(cpp[("compute", n)])] * (len(transports) + 1)
    for key in sorted(rows):
        *p, c = rows[key]
        print(("%-19s %8d" + " %10.3f" * (len(p) + 1) + " %10.2f" * len(p))
              % (key[0], key[1], *p, c, *[x / c for x in p]))


if __name__ == "__main__":
    main()
