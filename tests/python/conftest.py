"""Fixtures: a real geomfit-server process on a free loopback port."""
import os
import re
import signal
import subprocess
import tempfile

import numpy as np
import pytest


class ServerProcess:
    """geomfit-server started with --port=0; the port is read from its first line."""

    def __init__(self, *extra_args):
        binary = os.environ.get("GEOMFIT_SERVER_BINARY")
        if not binary or not os.path.exists(binary):
            raise RuntimeError("GEOMFIT_SERVER_BINARY must name the geomfit-server binary")
        self.proc = subprocess.Popen(
            [binary, "--host=127.0.0.1", "--port=0", "--log-level=warn", "--workers=2", *extra_args],
            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        line = self.proc.stdout.readline()
        match = re.search(r"listening on port (\d+)", line)
        if not match:
            self.kill()
            raise RuntimeError("geomfit-server did not start: %r" % line)
        self.address = "127.0.0.1:%s" % match.group(1)

    def kill(self, sig=signal.SIGKILL, timeout=30):
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            return self.proc.wait(timeout=timeout)
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
                self.proc.wait()


@pytest.fixture
def server():
    s = ServerProcess("--store=memory")
    yield s
    s.kill(signal.SIGTERM)


@pytest.fixture(params=["native", "grpcio"])
def transport(request):
    """The Python client's transport for update_positions and curvature: a test that
    takes this fixture runs once with each."""
    return request.param


@pytest.fixture
def data_dir():
    with tempfile.TemporaryDirectory(prefix="geomfit_py_") as d:
        yield d


def torus(n=24, m=12, R=1.0, r=0.3):
    """A UV torus: (positions, triangles) with counter-clockwise faces seen from outside."""
    u = 2 * np.pi * np.arange(n) / n
    v = 2 * np.pi * np.arange(m) / m
    U, V = np.meshgrid(u, v, indexing="ij")
    pos = np.stack([(R + r * np.cos(V)) * np.cos(U), (R + r * np.cos(V)) * np.sin(U), r * np.sin(V)], axis=-1)
    idx = np.arange(n * m).reshape(n, m)
    a, b = idx, np.roll(idx, -1, axis=0)
    c, d = np.roll(b, -1, axis=1), np.roll(a, -1, axis=1)
    tris = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return pos.reshape(-1, 3), tris.astype(np.int32)


@pytest.fixture
def torus_mesh():
    return torus(96, 48)
