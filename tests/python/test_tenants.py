"""--auth-tokens from the Python client and the CLI: the token goes with every call of
both transports; another tenant sees nothing; no token is UNAUTHENTICATED."""
import signal

import pytest

import geomfit
from conftest import ServerProcess, torus
from test_cli_remote import run

TOKEN_A, TOKEN_B = "alpha-token-0123456789", "beta-token-0123456789"


@pytest.fixture
def tenant_server(tmp_path):
    tokens = tmp_path / "tokens"
    tokens.write_text("%s alpha\n%s beta\n" % (TOKEN_A, TOKEN_B))
    s = ServerProcess("--store=memory", "--auth-tokens", str(tokens))
    yield s
    s.kill(signal.SIGTERM)


def test_tenants_through_both_transports(tenant_server, transport):
    pos, tris = torus(24, 12)
    with geomfit.Client(tenant_server.address, transport=transport, token=TOKEN_A) as a, \
            geomfit.Client(tenant_server.address, transport=transport, token=TOKEN_B) as b:
        info = a.upload(pos, tris, name="a")
        a.update_positions(info.mesh_id, pos * 2)  # native when in use
        assert a.curvature(info.mesh_id, degree=2).mean.shape == (len(pos),)
        assert [m.mesh_id for m in a.list_meshes()] == [info.mesh_id]
        assert b.list_meshes() == []
        for call in (lambda: b.update_positions(info.mesh_id, pos), lambda: b.curvature(info.mesh_id, degree=2)):
            with pytest.raises(geomfit.GeomfitError) as e:
                call()
            assert e.value.code.name == "NOT_FOUND"
    with geomfit.Client(tenant_server.address, transport=transport, max_attempts=1) as anonymous:
        with pytest.raises(geomfit.GeomfitError) as e:
            anonymous.list_meshes()
        assert e.value.code.name == "UNAUTHENTICATED"


def test_cli_token(tenant_server, tmp_path, monkeypatch):
    token_file = tmp_path / "token"
    token_file.write_text(TOKEN_A + "\n")
    monkeypatch.delenv("GEOMFIT_TOKEN", raising=False)
    r = run("list", "--server", tenant_server.address, check=False)
    assert r.returncode != 0 and "authorization: Bearer TOKEN" in r.stderr
    assert run("list", "--server", tenant_server.address, "--token-file", str(token_file)).stdout.startswith("mesh_id")
    monkeypatch.setenv("GEOMFIT_TOKEN", TOKEN_B)
    assert run("list", "--server", tenant_server.address).stdout.startswith("mesh_id")


def test_quota_names_itself(tmp_path, transport):
    tokens = tmp_path / "tokens"
    tokens.write_text("%s alpha\n%s beta\n" % (TOKEN_A, TOKEN_B))
    s = ServerProcess("--store=memory", "--auth-tokens", str(tokens), "--quota-meshes", "1")
    try:
        pos, tris = torus(24, 12)
        with geomfit.Client(s.address, transport=transport, token=TOKEN_A, max_attempts=1) as a, \
                geomfit.Client(s.address, transport=transport, token=TOKEN_B, max_attempts=1) as b:
            a.upload(pos, tris, name="first")
            with pytest.raises(geomfit.GeomfitError) as e:
                a.upload(pos, tris, name="second")
            assert e.value.code.name == "RESOURCE_EXHAUSTED"
            assert "tenant quota --quota-meshes=1 reached" in str(e.value)
            b.upload(pos, tris, name="second")  # beta's quota is beta's
    finally:
        s.kill(signal.SIGTERM)
