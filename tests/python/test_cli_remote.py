"""`geomfit --server` (remote mode) against the real server: same output as local."""
import os
import subprocess

import pytest

from conftest import ServerProcess


def cli():
    binary = os.environ.get("GEOMFIT_CLI_BINARY")
    if not binary or not os.path.exists(binary):
        raise RuntimeError("GEOMFIT_CLI_BINARY must name the geomfit binary")
    return binary


def run(*args, check=True):
    r = subprocess.run([cli(), *args], capture_output=True, text=True, timeout=120)
    if check and r.returncode != 0:
        raise AssertionError("geomfit %s failed (%d): %s" % (" ".join(args), r.returncode, r.stderr))
    return r


@pytest.fixture
def mesh_file(tmp_path):
    path = str(tmp_path / "torus.obj")
    run("generate", "torus", "--level", "10", "--output", path)
    return path


def test_remote_commands_and_outputs_match_local(server, mesh_file, tmp_path):
    address = server.address
    upload = run("upload", "--server", address, mesh_file, "--labels", "case=cli").stdout.splitlines()
    assert upload[0].startswith("mesh_id\trevision")
    mesh_id, revision = upload[1].split("\t")[:2]
    assert revision == "1"
    assert mesh_id in run("list", "--server", address).stdout
    assert run("info", "--server", address, mesh_id).stdout.splitlines()[1].startswith(mesh_id)

    local, remote = str(tmp_path / "local.tsv"), str(tmp_path / "remote.tsv")
    run("curvature", mesh_file, "--degree", "3", "--output", local)
    run("curvature", "--server", address, mesh_file, "--degree", "3", "--output", remote)
    assert open(remote).read() == open(local).read()
    vtp = str(tmp_path / "remote.vtp")
    run("curvature", "--server", address, mesh_id, "--output", vtp)
    assert "<VTKFile" in open(vtp).read(200)

    updated = run("update", "--server", address, mesh_id, mesh_file, "--expected-revision", "1").stdout
    assert updated.splitlines()[1].split("\t")[1] == "2"
    stale = run("update", "--server", address, mesh_id, mesh_file, "--expected-revision", "1", check=False)
    assert stale.returncode == 1
    assert "expected_revision 1" in stale.stderr

    run("delete", "--server", address, mesh_id)
    missing = run("info", "--server", address, mesh_id, check=False)
    assert missing.returncode == 1
    assert "not found" in missing.stderr


def test_remote_usage_errors():
    r = run("list", check=False)
    assert r.returncode == 2
    assert "--server" in r.stderr
