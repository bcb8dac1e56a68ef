#!/usr/bin/python3
"""Stalled server-stream readers: what a reader that reads nothing costs the server.

K clients ask ComputeDifferentials for every quantity (with diagnostics) of one N-vertex
torus and read nothing (16 KiB transport windows, as bench/README.md "Stalled readers"
describes); with --workers 1 a full read of the same request, sent after them, answers
once all their work has returned. The server's RSS and GetStatistics' inflight_bytes /
open_streams are then sampled, and again once --stream-idle-seconds has ended the
stalled streams.

    PYTHONPATH=clients/python:build/python /usr/bin/python3 bench/stalled_readers.py build/server/geomfit-server \\
        [--readers 8] [--m 200] [--idle 4]
"""
import argparse
import os
import subprocess
import sys
import time

import grpc

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "clients", "python"))
import geomfit  # noqa: E402
from geomfit.v1 import geomfit_pb2 as pb  # noqa: E402
from geomfit.v1 import geomfit_pb2_grpc as pb_grpc  # noqa: E402
from soak import rss_kib, torus  # noqa: E402

SMALL_WINDOW = [("grpc.http2.bdp_probe", 0), ("grpc.http2.lookahead_bytes", 16 << 10)]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("server")
    ap.add_argument("--port", type=int, default=50171)
    ap.add_argument("--readers", type=int, default=8)
    ap.add_argument("--m", type=int, default=200, help="torus of 3 m^2 vertices")
    ap.add_argument("--idle", type=float, default=4, help="--stream-idle-seconds")
    args = ap.parse_args()
    server = subprocess.Popen([args.server, "--port", str(args.port), "--store", "memory", "--cache-bytes", "1G",
                               "--stream-idle-seconds", str(args.idle), "--workers", "1", "--threads", "2",
                               "--log-level", "error"])
    target = f"127.0.0.1:{args.port}"
    try:
        grpc.channel_ready_future(grpc.insecure_channel(target)).result(timeout=20)
        client = geomfit.Client(target, timeout=300.0)
        stub = pb_grpc.GeomFitStub(grpc.insecure_channel(target))
        p, f = torus(args.m)
        mesh_id = client.upload(p, f, name="stalled").mesh_id
        request = pb.ComputeDifferentialsRequest(mesh_id=mesh_id, quantities=list(range(1, 7)), diagnostics=True)
        idle_rss = rss_kib(server.pid) / 1024
        calls = []
        for _ in range(args.readers):
            channel = grpc.insecure_channel(target, options=SMALL_WINDOW)
            calls.append((channel, pb_grpc.GeomFitStub(channel).ComputeDifferentials(request, timeout=300)))
        deadline = time.time() + 2  # a server before this change counted no server streams
        while stub.GetStatistics(pb.GetStatisticsRequest()).open_streams < args.readers and time.time() < deadline:
            time.sleep(0.01)
        start = time.time()
        response = sum(c.ByteSize() for c in stub.ComputeDifferentials(request, timeout=300))
        stats = stub.GetStatistics(pb.GetStatisticsRequest())
        held_rss = rss_kib(server.pid) / 1024
        time.sleep(1.5 * args.idle)  # the watchdog ends a stream 1 to 1.25 idle times after its last write
        after = stub.GetStatistics(pb.GetStatisticsRequest())
        after_rss = rss_kib(server.pid) / 1024
        print(f"{len(p)} vertices, response {response / 2**20:.1f} MiB, {args.readers} stalled readers "
              f"(work done in {time.time() - start:.1f} s)")
        print("| | RSS (MiB) | inflight_bytes | open_streams |")
        print("|---|---|---|---|")
        print(f"| mesh stored | {idle_rss:.0f} | | |")
        print(f"| readers stalled, work done | {held_rss:.0f} | {stats.inflight_bytes} | {stats.open_streams} |")
        print(f"| after the idle timeout | {after_rss:.0f} | {after.inflight_bytes} | {after.open_streams} |")
        for channel, call in calls:
            call.cancel()
            channel.close()
    finally:
        server.terminate()
        server.wait(timeout=30)


if __name__ == "__main__":
    main()
