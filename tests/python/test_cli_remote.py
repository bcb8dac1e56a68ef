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
    # A file is accepted too, as by every command taking MESH (uploaded idempotently under
    # its file name, without labels: another id than the labelled upload, same geometry).
    by_file = run("info", "--server", address, mesh_file).stdout.splitlines()[1].split("\t")
    assert by_file[0].startswith("m-") and by_file[2:4] == upload[1].split("\t")[2:4]
    assert run("info", "--server", address, mesh_file).stdout.splitlines()[1].split("\t")[0] == by_file[0]

    local, remote = str(tmp_path / "local.tsv"), str(tmp_path / "remote.tsv")
    run("curvature", mesh_file, "--degree", "3", "--output", local)
    run("curvature", "--server", address, mesh_file, "--degree", "3", "--output", remote)
    assert open(remote).read() == open(local).read()
    vtp = str(tmp_path / "remote.vtp")
    run("curvature", "--server", address, mesh_id, "--output", vtp)
    assert b"<VTKFile" in open(vtp, "rb").read(200)  # binary appended: read as bytes
    # The mesh is downloaded for VTK outputs: the same bytes as the local .vtu.
    local_vtu, remote_vtu = str(tmp_path / "local.vtu"), str(tmp_path / "remote.vtu")
    run("curvature", mesh_file, "--degree", "3", "--output", local_vtu)
    run("curvature", "--server", address, mesh_id, "--degree", "3", "--output", remote_vtu)
    assert open(remote_vtu, "rb").read() == open(local_vtu, "rb").read()

    updated = run("update", "--server", address, mesh_id, mesh_file, "--expected-revision", "1").stdout
    assert updated.splitlines()[1].split("\t")[1] == "2"
    stale = run("update", "--server", address, mesh_id, mesh_file, "--expected-revision", "1", check=False)
    assert stale.returncode == 1
    assert "expected_revision 1" in stale.stderr

    run("delete", "--server", address, mesh_id)
    missing = run("info", "--server", address, mesh_id, check=False)
    assert missing.returncode == 1
    assert "not found" in missing.stderr


def test_normal_degree_from_the_cli_and_python_client(server, tmp_path):
    """--normal-degree / normal_degree=: the same refined normals locally, over the CLI's
    --server and from Client.curvature, and other normals than the plain degree-2 fit."""
    import numpy as np
    import geomfit
    sphere = str(tmp_path / "s.obj")
    run("generate", "sphere", "--level", "6", "--output", sphere)
    local, remote = str(tmp_path / "local.tsv"), str(tmp_path / "remote.tsv")
    run("curvature", sphere, "--degree", "2", "--normal-degree", "3", "--output", local)
    run("curvature", "--server", server.address, sphere, "--degree", "2", "--normal-degree", "3", "--output", remote)
    assert open(remote).read() == open(local).read()
    cli_normals = np.loadtxt(local)[:, 0:3]
    with geomfit.Client(server.address) as client:
        mesh_id = client.upload_file(sphere).mesh_id
        plain = client.curvature(mesh_id, degree=2, quantities=["normals"])
        refined = client.curvature(mesh_id, degree=2, quantities=["normals"], normal_degree=3)
        with pytest.raises(geomfit.GeomfitError) as bad:
            client.curvature(mesh_id, degree=2, normal_degree=1)
        assert bad.value.code.name == "INVALID_ARGUMENT"
        assert "normal_degree = 1" in bad.value.details
    assert np.max(np.abs(refined.normals - cli_normals)) <= 1e-12
    assert np.max(np.abs(refined.normals - plain.normals)) > 1e-8


def test_remote_usage_errors():
    r = run("list", check=False)
    assert r.returncode == 2
    assert "--server" in r.stderr


def test_chapter4_commands_remote_match_local(server, tmp_path):
    """project, refine, nodes and integrate give byte-identical results over gRPC."""
    address = server.address
    sphere = str(tmp_path / "s.obj")
    run("generate", "sphere", "--level", "6", "--output", sphere)
    points = tmp_path / "xyz.txt"
    points.write_text("0 0 1.1\n0.5 0.5 0.6\n")
    faces = tmp_path / "fxe.txt"
    faces.write_text("0 0.25 0.25\n3 0.1 0.6\n")
    for args in (["integrate", sphere, "--degree", "4"],
                 ["project", sphere, "--points", str(points), "--method", "cmf"],
                 ["project", sphere, "--face-points", str(faces)]):
        assert run(*args, "--server", address).stdout == run(*args).stdout, args
    local, remote = str(tmp_path / "local.obj"), str(tmp_path / "remote.obj")
    run("refine", sphere, "--factor", "3", "--output", local)
    stored = run("refine", sphere, "--factor", "3", "--output", remote, "--server", address)
    assert "stored the refined mesh as m-" in stored.stderr
    assert open(local).read() == open(remote).read()
    run("nodes", sphere, "--order", "3", "--output", str(tmp_path / "l"))
    run("nodes", sphere, "--order", "3", "--output", str(tmp_path / "r"), "--server", address)
    for suffix in (".nodes.tsv", ".elements.tsv"):
        assert open(str(tmp_path / "l") + suffix).read() == open(str(tmp_path / "r") + suffix).read()
    # Bad input is a one-line error naming the point, and the server stays up.
    faces.write_text("0 0.9 0.5\n")
    bad = run("project", sphere, "--face-points", str(faces), "--server", address, check=False)
    assert bad.returncode == 1
    assert "outside triangle face 0" in bad.stderr
    assert run("list", "--server", address).returncode == 0


def test_refine_job_and_jobs_commands(server, mesh_file, tmp_path):
    address = server.address
    out = str(tmp_path / "fine.obj")
    r = run("refine", "--server", address, mesh_file, "--job", "--levels", "2", "--degree", "2", "--output", out)
    rows = [line.split("\t") for line in r.stdout.splitlines()]
    assert rows[0][:2] == ["level", "mesh_id"] and [row[0] for row in rows[1:]] == ["1", "2"]
    assert int(rows[2][4]) == 4 * int(rows[1][4])
    assert "stored" in r.stderr and "SUCCEEDED" in r.stderr
    assert os.path.getsize(out) > 0
    listed = run("jobs", "list", "--server", address).stdout.splitlines()
    job_id, kind, state = listed[1].split("\t")[:3]
    assert (kind, state) == ("refine", "SUCCEEDED")
    watched = run("jobs", "watch", "--server", address, job_id, "--from", "3").stdout.splitlines()
    assert watched[0].startswith("job %s #3 " % job_id) and "SUCCEEDED" in watched[-1]
    assert run("jobs", "cancel", "--server", address, job_id).stdout.splitlines()[1].split("\t")[2] == "SUCCEEDED"
    missing = run("jobs", "get", "--server", address, "j-nope", check=False)
    assert missing.returncode == 1 and "not found" in missing.stderr
    bad = run("refine", "--server", address, mesh_file, "--job", "--levels", "0", check=False)
    assert bad.returncode == 2 and "--levels" in bad.stderr


def test_health_reports_serving_and_fails_when_nothing_listens(server):
    r = run("health", "--server", server.address)
    assert r.stdout == "SERVING\n"
    r = run("health", "--server", server.address, "--service", "geomfit.v1.GeomFit")
    assert r.stdout == "SERVING\n"
    import socket
    with socket.socket() as s:  # a port with nothing listening
        s.bind(("127.0.0.1", 0))
        closed = "127.0.0.1:%d" % s.getsockname()[1]
    r = run("health", "--server", closed, "--timeout", "2", check=False)
    assert r.returncode == 1, r.stderr
    assert r.stderr.startswith("geomfit: error: ") and "UNAVAILABLE" not in r.stdout


def test_remote_progress_comes_from_the_server(server, tmp_path):
    """--progress draws the server's phases (fit, project, evaluate points, integrate;
    smooth i/S with --noise on) for the remote chapter-4 commands and curvature; --no-progress (and a non-terminal
    stderr) draws nothing; outputs are the same either way."""
    address = server.address
    torus = str(tmp_path / "t.obj")
    run("generate", "torus", "--level", "12", "--output", torus)
    points = tmp_path / "xyz.txt"
    points.write_text("".join("%g 0 %g\n" % (1.0 + 0.1 * k / 50, 0.31) for k in range(50)))
    commands = {
        ("project", torus, "--points", str(points), "--degree", "4"): ["fit", "project"],
        ("nodes", torus, "--order", "2", "--output", str(tmp_path / "n"), "--degree", "4"): ["evaluate points"],
        ("integrate", torus, "--degree", "4"): ["integrate"],
        ("refine", torus, "--output", str(tmp_path / "r.obj"), "--degree", "4"): ["evaluate points"],
        ("curvature", torus, "--degree", "3"): ["fit", "compute"],
        # every pass of the noise-aware fit, from the server
        # (a clean mesh: light noise, two smoothing and two local passes at degree 4)
        ("curvature", torus, "--degree", "4", "--noise", "on"): ["smooth 1/4", "smooth 2/4", "smooth 4/4", "fit"],
    }
    for args, phases in commands.items():
        shown = run(*args, "--server", address, "--progress")
        lines = shown.stderr.replace("\r", "\n").split("\n")
        for phase in phases:
            finished = [line for line in lines if line.startswith(phase + " ") and "100%" in line]
            assert finished, (args, phase, shown.stderr)
        quiet = run(*args, "--server", address, "--no-progress")
        assert "%" not in quiet.stderr and not any(p in quiet.stderr for p in phases if p != "compute"), quiet.stderr
        assert quiet.stdout == shown.stdout, args
        assert run(*args, "--server", address).stderr == quiet.stderr  # stderr is not a terminal here
