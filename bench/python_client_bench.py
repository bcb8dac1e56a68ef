#!/usr/bin/python3
"""Python client timings against a real geomfit-server: curvature on cached fits at
1k, 10k and 100k vertices, and an FSI-style loop (update_positions + curvature).

    PYTHONPATH=clients/python /usr/bin/python3 bench/python_client_bench.py \
        build/server/geomfit-server [--store memory|sqlite] [--reps 20] [--threads 1]

Compare the "rpc ms" column with BM_RpcCurvatureCachedFits of service_rpc_bench
(the C++ client) to get the Python client's overhead.
"""
import argparse
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


def torus(vertices, R=1.0, r=0.3):
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


def median_ms(fn, reps):
    times = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        times.append(1e3 * (time.perf_counter() - t))
    return statistics.median(times)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("server_binary")
    ap.add_argument("--store", default="memory", choices=["memory", "sqlite"])
    ap.add_argument("--reps", type=int, default=20)
    ap.add_argument("--threads", type=int, default=1,
                    help="server --threads (numeric threads per computation); 1 matches "
                         "GEOMFIT_BENCH_THREADS=1 of service_rpc_bench")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="geomfit_pybench_") as data_dir:
        proc = subprocess.Popen([args.server_binary, "--host=127.0.0.1", "--port=0", "--log-level=warn",
                                 "--store=" + args.store, "--data-dir=" + data_dir,
                                 "--threads=%d" % args.threads],
                                stdout=subprocess.PIPE, text=True)
        try:
            port = re.search(r"port (\d+)", proc.stdout.readline()).group(1)
            with geomfit.Client("127.0.0.1:" + port) as client:
                print("%-8s %10s %14s %12s" % ("vertices", "rpc ms", "server eval ms", "fsi ms/step"))
                for n in (1000, 10000, 100000):
                    pos, tris = torus(n)
                    mesh_id = client.upload(pos, tris, name="bench").mesh_id
                    eval_ms = client.curvature(mesh_id).summary.evaluate_ms  # fit once
                    rpc = median_ms(lambda: client.curvature(mesh_id), args.reps)
                    step = [0]

                    def fsi():
                        step[0] += 1
                        info = client.update_positions(mesh_id, pos + 1e-4 * (step[0] % 2))
                        client.curvature(mesh_id, revision=info.revision)
                    fsi_ms = median_ms(fsi, max(3, args.reps // 4)) if n <= 10000 else float("nan")
                    print("%-8d %10.3f %14.3f %12.3f" % (len(pos), rpc, eval_ms, fsi_ms))
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(timeout=30)


if __name__ == "__main__":
    main()
