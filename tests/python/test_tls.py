"""TLS and mTLS against the real server: the Python client (both transports) and the
CLI, with certificates made for the test (tests/tls/make_certs.sh)."""
import os
import signal
import socket
import subprocess
import urllib.request

import pytest

import geomfit
from conftest import ServerProcess, torus
from test_cli_remote import run

MAKE_CERTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tls", "make_certs.sh")


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def certs(tmp_path_factory):
    d = str(tmp_path_factory.mktemp("certs"))
    subprocess.run([MAKE_CERTS, d], check=True)
    return lambda name: os.path.join(d, name)


@pytest.fixture
def mtls_server(certs):
    s = ServerProcess("--store=memory", "--tls-cert", certs("server.pem"), "--tls-key", certs("server.key"),
                      "--tls-client-ca", certs("ca.pem"))
    yield s
    s.kill(signal.SIGTERM)


def test_python_client_mtls_round_trip(mtls_server, certs, transport):
    pos, tris = torus(24, 12)
    with geomfit.Client(mtls_server.address, transport=transport, tls_ca=certs("ca.pem"),
                        tls_cert=certs("client.pem"), tls_key=certs("client.key")) as c:
        assert c.tls
        info = c.upload(pos, tris, name="t")
        c.update_positions(info.mesh_id, pos * 2)  # one message: the native transport when in use
        d = c.curvature(info.mesh_id, degree=2)
        assert d.mean.shape == (len(pos),)
    with geomfit.Client(mtls_server.address, transport=transport, tls_ca=certs("ca.pem"), max_attempts=1,
                        timeout=10) as c:  # TLS without a client certificate
        with pytest.raises(geomfit.GeomfitError) as e:
            c.list_meshes()
        assert e.value.code.name == "UNAVAILABLE"
        with pytest.raises(geomfit.GeomfitError):
            c.update_positions(info.mesh_id, pos)


def test_cli_tls_flags(mtls_server, certs):
    address = mtls_server.address
    tls = ["--tls-ca", certs("ca.pem"), "--tls-cert", certs("client.pem"), "--tls-key", certs("client.key")]
    assert run("list", "--server", address, *tls).stdout.startswith("mesh_id\t")
    r = run("list", "--server", address, "--tls-ca", certs("ca.pem"), check=False)  # no client certificate
    assert r.returncode != 0 and "UNAVAILABLE" in r.stderr
    r = run("list", "--server", address, "--tls-ca", "/nonexistent.pem", check=False)
    assert r.returncode != 0 and "/nonexistent.pem" in r.stderr


def test_metrics_stay_plaintext_with_tls(certs):
    """civetweb (Debian 12) crashes serving TLS with OpenSSL 3 (server/tls.h): the
    metrics port serves plaintext HTTP, also when gRPC is TLS."""
    port = free_port()
    s = ServerProcess("--store=memory", "--tls-cert", certs("server.pem"), "--tls-key", certs("server.key"),
                      "--metrics-port", str(port))
    try:
        body = urllib.request.urlopen("http://127.0.0.1:%d/metrics" % port, timeout=10).read()
        assert b"geomfit_" in body
    finally:
        s.kill(signal.SIGTERM)


def test_warns_when_serving_other_hosts_without_tls(tmp_path):
    """The default listens on loopback; --host=0.0.0.0 without TLS logs a warning line."""
    binary = os.environ["GEOMFIT_SERVER_BINARY"]
    err = tmp_path / "stderr.txt"
    for args, warned in ((["--host=0.0.0.0"], True), ([], False)):
        with open(err, "w") as f:
            p = subprocess.Popen([binary, "--port=0", "--store=memory", *args], stdout=subprocess.PIPE,
                                 stderr=f, text=True)
            try:
                line = p.stdout.readline()
                assert "listening on port" in line
            finally:
                p.send_signal(signal.SIGTERM)
                p.wait(timeout=30)
        text = err.read_text()
        assert ("without TLS" in text) == warned, text
        if not warned:
            assert "listening on 127.0.0.1:" in text
