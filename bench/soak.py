#!/usr/bin/python3
"""Soak: a dozen clients against one geomfit-server with small budgets, sampling its RSS.

The store is SQLite in a temporary directory (on disk, outside the RSS bound).
Clients (threads, each its own channel): uploads of new tori, position updates,
curvature at degrees 1-6, reconstruction (ProjectPoints) and refinement, deletes,
downloads that stop reading, and stalled upload streams (a header declaring a large
mesh, then silence until --stream-idle-seconds ends them). The server's RSS
(/proc/PID/status VmRSS) is sampled every 100 ms; the report gives the peak, the bound
cache-bytes + max-inflight-bytes and the constant C = peak - bound, plus the completed
calls per second.

With --allocators, the same soak runs once per allocator, preloaded with LD_PRELOAD
("build" = none: the binary's own), and prints one table row each (bench/README.md, "Soak").

    PYTHONPATH=clients/python:build/python /usr/bin/python3 bench/soak.py build/server/geomfit-server \\
        [--seconds 60] [--cache-bytes 64M] [--max-inflight-bytes 32M] [--allocators build,jemalloc,mimalloc]
"""
import argparse
import os
import random
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time

import grpc
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "clients", "python"))
import geomfit  # noqa: E402
from geomfit.v1 import geomfit_pb2 as pb  # noqa: E402
from geomfit.v1 import geomfit_pb2_grpc as pb_grpc  # noqa: E402

# "build": no preload, the binary's own allocator (mimalloc when linked, the default;
# glibc malloc in a -DGEOMFIT_MIMALLOC=OFF build). A preloaded library comes before both.
ALLOCATORS = {
    "build": None,
    "jemalloc": "/usr/lib/x86_64-linux-gnu/libjemalloc.so.2",
    "mimalloc": "/usr/lib/x86_64-linux-gnu/libmimalloc.so.2",
}


def parse_bytes(s):
    m = re.fullmatch(r"(\d+)([KMG]?)", s)
    if not m:
        raise argparse.ArgumentTypeError(f"bad byte count {s!r}")
    return int(m.group(1)) << {"": 0, "K": 10, "M": 20, "G": 30}[m.group(2)]


def torus(m, R=1.0, r=0.3, seed=0):
    """A jittered 3m x m torus grid: positions (3m^2 x 3) and quads."""
    n = 3 * m
    u = 2 * np.pi * np.arange(n) / n
    v = 2 * np.pi * np.arange(m) / m
    U, V = np.meshgrid(u, v, indexing="ij")
    p = np.stack([(R + r * np.cos(V)) * np.cos(U), (R + r * np.cos(V)) * np.sin(U), r * np.sin(V)], -1).reshape(-1, 3)
    p += np.random.default_rng(seed).normal(scale=1e-4, size=p.shape)
    i, j = np.meshgrid(np.arange(n), np.arange(m), indexing="ij")
    a = i * m + j
    b = ((i + 1) % n) * m + j
    c = ((i + 1) % n) * m + (j + 1) % m
    d = i * m + (j + 1) % m
    return p, np.stack([a, b, c, d], -1).reshape(-1, 4).astype(np.int32)


def rss_kib(pid):
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    return 0


class Soak:
    def __init__(self, port, seconds, idle):
        self.target = f"127.0.0.1:{port}"
        self.stop_at = time.time() + seconds
        self.idle = idle
        self.lock = threading.Lock()
        self.calls = 0
        self.errors = {}
        self.ids = []

    def running(self):
        return time.time() < self.stop_at

    def count(self, error=None):
        with self.lock:
            self.calls += 1
            if error is not None:
                self.errors[error] = self.errors.get(error, 0) + 1

    def run_client(self, kind, seed):
        rnd = random.Random(seed)
        client = geomfit.Client(self.target, timeout=60.0, max_attempts=1)
        stub = pb_grpc.GeomFitStub(grpc.insecure_channel(self.target))
        while self.running():
            try:
                self.step(kind, rnd, client, stub)
                self.count()
            except geomfit.GeomfitError as e:
                self.count(e.code.name)
            except grpc.RpcError as e:
                self.count(e.code().name)
        client.close()

    def pick(self, rnd):
        with self.lock:
            return rnd.choice(self.ids) if self.ids else None

    def step(self, kind, rnd, client, stub):
        if kind == "upload":
            p, f = torus(rnd.choice((20, 40, 60, 80)), seed=rnd.randrange(1 << 30))
            info = client.upload(p, f, name=f"soak-{rnd.randrange(1 << 30)}")
            with self.lock:
                self.ids.append((info.mesh_id, len(p)))
                del self.ids[:-20]
            return
        picked = self.pick(rnd)
        if kind == "stall":
            # A header declaring 100k vertices and faces (8 MB in flight), then silence:
            # the idle timeout ends it.
            gate = threading.Event()

            def requests():
                yield pb.UploadMeshRequest(header=pb.MeshHeader(num_vertices=100000, num_faces=100000))
                gate.wait(self.idle * 3)

            try:
                stub.UploadMesh(requests(), timeout=self.idle * 3)
            finally:
                gate.set()
            return
        if picked is None:
            time.sleep(0.05)
            return
        mesh_id, n = picked
        if kind == "update":
            p, _ = torus(int(round(np.sqrt(n / 3))), seed=rnd.randrange(1 << 30))
            client.update_positions(mesh_id, p)
        elif kind == "curvature":
            client.curvature(mesh_id, degree=rnd.randint(1, 6))
        elif kind == "reconstruct":
            faces = np.array([rnd.randrange(n // 2) for _ in range(200)], dtype=np.int32)
            client.project(mesh_id, faces=faces, natural=np.full((200, 2), 0.25))
        elif kind == "delete":
            time.sleep(0.5)
            client.delete_mesh(mesh_id)
            with self.lock:
                self.ids = [x for x in self.ids if x[0] != mesh_id]
        elif kind == "slow-download":
            # Reads the first chunk and stops for a while, then cancels.
            call = stub.DownloadMesh(pb.DownloadMeshRequest(mesh_id=mesh_id, chunk_rows=64))
            next(call)
            time.sleep(1.0)
            call.cancel()


KINDS = ["upload", "upload", "update", "update", "curvature", "curvature", "curvature", "reconstruct",
         "delete", "stall", "stall", "slow-download"]


def soak_once(args, allocator):
    data_dir = tempfile.mkdtemp(prefix="geomfit-soak-")
    env = dict(os.environ)
    if ALLOCATORS[allocator]:
        env["LD_PRELOAD"] = ALLOCATORS[allocator]
    server = subprocess.Popen(
        [args.server, "--port", str(args.port), "--store", "sqlite", "--data-dir", data_dir, "--cache-bytes", str(args.cache_bytes),
         "--max-inflight-bytes", str(args.max_inflight_bytes), "--stream-idle-seconds", str(args.idle),
         "--workers", "2", "--threads", "1", "--log-level", "error"], env=env)
    try:
        ch = grpc.insecure_channel(f"127.0.0.1:{args.port}")
        grpc.channel_ready_future(ch).result(timeout=20)
        soak = Soak(args.port, args.seconds, args.idle)
        threads = [threading.Thread(target=soak.run_client, args=(k, i), daemon=True) for i, k in enumerate(KINDS)]
        for t in threads:
            t.start()
        peak = 0
        samples = []
        while soak.running() or any(t.is_alive() for t in threads):
            kib = rss_kib(server.pid)
            peak = max(peak, kib)
            samples.append(kib)
            time.sleep(0.1)
            if time.time() > soak.stop_at + 120:
                break
        if server.poll() is not None:
            raise RuntimeError(f"{allocator}: the server exited with {server.returncode} during the soak")
        stats = pb_grpc.GeomFitStub(ch).GetStatistics(pb.GetStatisticsRequest(), timeout=10)
        return dict(allocator=allocator, peak_mib=peak / 1024, mean_mib=sum(samples) / len(samples) / 1024,
                    calls=soak.calls, per_s=soak.calls / args.seconds, errors=soak.errors,
                    inflight_after=stats.inflight_bytes, open_after=stats.open_streams)
    finally:
        server.terminate()
        server.wait(timeout=30)
        shutil.rmtree(data_dir, ignore_errors=True)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("server")
    ap.add_argument("--seconds", type=float, default=60)
    ap.add_argument("--port", type=int, default=50161)
    ap.add_argument("--cache-bytes", type=parse_bytes, default=64 << 20)
    ap.add_argument("--max-inflight-bytes", type=parse_bytes, default=32 << 20)
    ap.add_argument("--idle", type=float, default=5, help="--stream-idle-seconds")
    ap.add_argument("--allocators", default="build")
    args = ap.parse_args()
    bound = (args.cache_bytes + args.max_inflight_bytes) / (1 << 20)
    print(f"cache-bytes {args.cache_bytes >> 20} MiB + max-inflight-bytes {args.max_inflight_bytes >> 20} MiB"
          f" = {bound:.0f} MiB; {len(KINDS)} clients for {args.seconds:.0f} s")
    print("| allocator | RSS peak (MiB) | RSS mean (MiB) | C = peak - budgets (MiB) | calls/s | errors | in flight after |")
    print("|---|---|---|---|---|---|---|")
    for allocator in args.allocators.split(","):
        r = soak_once(args, allocator)
        errors = ", ".join(f"{k} {v}" for k, v in sorted(r["errors"].items())) or "-"
        print(f"| {allocator} | {r['peak_mib']:.0f} | {r['mean_mib']:.0f} | {r['peak_mib'] - bound:.0f} | "
              f"{r['per_s']:.1f} | {errors} | {r['inflight_after']} B, {r['open_after']} streams |", flush=True)


if __name__ == "__main__":
    main()
