"""Cache-affine routing: two geomfit-servers behind nginx (deploy/router/nginx.conf) on
loopback. Every mesh's calls after its upload land on one replica, and stopping a
replica moves only its meshes, which the client recovers by re-uploading.

    GEOMFIT_SERVER_BINARY=... PYTHONPATH=clients/python:build/python python3 deploy/router/test_router.py
Exit status 77 (skipped) when nginx is not installed.
"""
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time

import grpc
import numpy as np

import geomfit

HERE = os.path.dirname(os.path.abspath(__file__))
NUM_MESHES = 20


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def torus(n, m, R=1.0, r=0.3):
    u, v = np.meshgrid(2 * np.pi * np.arange(n) / n, 2 * np.pi * np.arange(m) / m, indexing="ij")
    pos = np.stack([(R + r * np.cos(v)) * np.cos(u), (R + r * np.cos(v)) * np.sin(u), r * np.sin(v)], -1)
    idx = np.arange(n * m).reshape(n, m)
    a, b = idx, np.roll(idx, -1, axis=0)
    c, d = np.roll(b, -1, axis=1), np.roll(a, -1, axis=1)
    tris = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return pos.reshape(-1, 3), tris.astype(np.int32)


class Server:
    def __init__(self, binary):
        self.proc = subprocess.Popen([binary, "--host=127.0.0.1", "--port=0", "--store=memory", "--log-level=error",
                                      "--drain-seconds=2"], stdout=subprocess.PIPE, text=True)
        match = re.search(r"listening on port (\d+)", self.proc.stdout.readline())
        assert match, "geomfit-server did not start"
        self.address = "127.0.0.1:" + match.group(1)

    def stop(self):
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            assert self.proc.wait(timeout=30) == 0


def router_conf(template, listen, upstreams, prefix):
    """deploy/router/nginx.conf with loopback addresses and paths under `prefix`."""
    conf = open(template).read()
    conf = re.sub(r"^\s*server geomfit-\d\.geomfit-headless:50051(.*)\n", "", conf, flags=re.M)
    servers = "".join("    server %s max_fails=1 fail_timeout=10s;\n" % u for u in upstreams)
    conf = conf.replace("    hash $http_x_mesh_id consistent;\n", "    hash $http_x_mesh_id consistent;\n" + servers)
    conf = conf.replace("listen 50051 http2;", "listen 127.0.0.1:%d http2;" % listen)
    conf = conf.replace("/tmp/geomfit-router", os.path.join(prefix, "router"))
    conf = conf.replace("worker_processes auto;", "worker_processes 1;\ndaemon off;")
    assert conf.count("server 127.0.0.1:") == len(upstreams), conf
    return conf


def stats(address):
    """(calls by method, errors by method, fitting-cache hits, stored mesh ids) of one replica."""
    with geomfit.Client(address, transport="grpcio") as c:
        s = c.statistics()
        calls = {m.method: m.count for m in s.methods}
        errors = {m.method: m.errors for m in s.methods}
        hits = {t.tier: t.hits for t in s.caches}["fitting"]
        return calls, errors, hits, {m.mesh_id for m in c.list_meshes()}


def main():
    nginx = shutil.which("nginx") or ("/usr/sbin/nginx" if os.path.exists("/usr/sbin/nginx") else None)
    if nginx is None:
        print("SKIPPED router test: nginx is not installed (bash deploy/install-deps.sh)")
        return 77
    binary = os.environ["GEOMFIT_SERVER_BINARY"]
    prefix = tempfile.mkdtemp(prefix="geomfit_router_")
    servers = [Server(binary), Server(binary)]
    port = free_port()
    conf = os.path.join(prefix, "nginx.conf")
    with open(conf, "w") as f:
        f.write(router_conf(os.path.join(HERE, "nginx.conf"), port, [s.address for s in servers], prefix))
    router = subprocess.Popen([nginx, "-e", "stderr", "-p", prefix, "-c", conf])
    try:
        target = "127.0.0.1:%d" % port
        for _ in range(100):
            with socket.socket() as s:
                if s.connect_ex(("127.0.0.1", port)) == 0:
                    break
            time.sleep(0.05)
        meshes = {}
        # Uploads through grpcio (Python metadata); curvature through the C++ client
        # (geomfit._native when built); a grpcio-only client for the other calls.
        with geomfit.Client(target) as client, geomfit.Client(target, transport="grpcio") as py:
            for i in range(NUM_MESHES):
                positions, faces = torus(12 + i, 8)
                name = "mesh-%02d" % i
                predicted = geomfit.mesh_id_of(positions, faces, name)
                info = client.upload(positions, faces, name=name)
                assert info.mesh_id == predicted, (info.mesh_id, predicted)
                meshes[info.mesh_id] = (positions, faces, name)
            for mesh_id in meshes:
                first = client.curvature(mesh_id, degree=2)
                second = py.curvature(mesh_id, degree=2)
                assert np.array_equal(first.mean, second.mean)
                assert py.get_mesh(mesh_id).mesh_id == mesh_id
                assert py.project(mesh_id, faces=[0], natural=[[0.25, 0.25]])["positions"].shape == (1, 3)

            # Each mesh is on exactly one replica, and every call on it landed there.
            before = [stats(s.address) for s in servers]
            owner = {}
            for r, (_, _, _, ids) in enumerate(before):
                for mesh_id in ids:
                    assert mesh_id not in owner, "%s on both replicas" % mesh_id
                    owner[mesh_id] = r
            assert set(owner) == set(meshes), "some meshes are on no replica"
            for r, (calls, errors, hits, ids) in enumerate(before):
                n = len(ids)
                print("replica %d (%s): %d meshes; UploadMesh %d, ComputeDifferentials %d, GetMesh %d, "
                      "ProjectPoints %d calls; fitting-cache hits %d; errors %d" % (
                          r, servers[r].address, n, calls.get("UploadMesh", 0), calls.get("ComputeDifferentials", 0),
                          calls.get("GetMesh", 0), calls.get("ProjectPoints", 0), hits, sum(errors.values())))
                assert n > 0, "consistent hashing put every mesh on one replica"
                assert calls.get("UploadMesh", 0) == n
                assert calls.get("ComputeDifferentials", 0) == 2 * n
                assert calls.get("GetMesh", 0) == n and calls.get("ProjectPoints", 0) == n
                assert hits >= n, "the second curvature of each mesh is a fitting-cache hit"
                assert sum(errors.values()) == 0, errors

            # Losing replica 1 moves only its meshes: replica 0's meshes are served as
            # before; replica 1's come back NOT_FOUND from replica 0 until re-uploaded.
            servers[1].stop()
            lost = {m for m, r in owner.items() if r == 1}
            not_found = set()
            for mesh_id, (positions, faces, name) in meshes.items():
                try:
                    py.curvature(mesh_id, degree=2)
                except geomfit.GeomfitError as e:
                    assert e.code == grpc.StatusCode.NOT_FOUND, e
                    not_found.add(mesh_id)
                    assert py.upload(positions, faces, name=name).mesh_id == mesh_id
                    py.curvature(mesh_id, degree=2)
            assert not_found == lost, (sorted(not_found), sorted(lost))
            calls, errors, hits, ids = stats(servers[0].address)
            assert ids == set(meshes)
            assert calls["UploadMesh"] == NUM_MESHES and errors["ComputeDifferentials"] == len(lost)
            print("replica 1 stopped: its %d meshes moved to replica 0 (NOT_FOUND, re-uploaded); replica 0's %d "
                  "meshes stayed; replica 0 now: UploadMesh %d, ComputeDifferentials %d, fitting-cache hits %d" % (
                      len(lost), NUM_MESHES - len(lost), calls["UploadMesh"], calls["ComputeDifferentials"], hits))
        print("router test: 1 passed, 0 failed")
        return 0
    finally:
        router.send_signal(signal.SIGQUIT)
        try:
            router.wait(timeout=10)
        except subprocess.TimeoutExpired:
            router.kill()
        for s in servers:
            if s.proc.poll() is None:
                s.proc.kill()
                s.proc.wait()
        shutil.rmtree(prefix, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
