"""Membranes from Python (chapter 6), the issue's user story: upload a sphere, solve it
under a pressure while watching the Newton iterations, download the deformed revision
and read its pressure back with ComputeMembrane (= the pressure solved for); bad inputs
name their fields; `geomfit membrane solve` and `geomfit membrane pressure`, --local and
--server, agree with each other and with the closed-form radius."""
import os
import subprocess

import grpc
import numpy as np
import pytest

import geomfit
from geomfit.v1 import geomfit_pb2 as pb
import vtk  # noqa: E402  (python3-vtk9, installed by scripts/install-deps.sh)
from vtk.util.numpy_support import vtk_to_numpy  # noqa: E402

RADIUS = 1.0080320  # unit sphere, E = 100, nu = 0.2, [p] = 2 (CHAPTERS-5-6.md)
MATERIAL = dict(young_modulus=100.0, poisson_ratio=0.2)


def cli(*args, ok=True):
    binary = os.environ.get("GEOMFIT_CLI_BINARY")
    assert binary and os.path.exists(binary), "GEOMFIT_CLI_BINARY must name the geomfit binary"
    r = subprocess.run([binary, *args], capture_output=True, text=True, timeout=120)
    if ok:
        assert r.returncode == 0, "geomfit %s failed (%d): %s" % (" ".join(args), r.returncode, r.stderr)
    return r


@pytest.fixture
def sphere_obj(data_dir):
    path = os.path.join(data_dir, "sphere.obj")
    cli("generate", "sphere", "--level", "8", "--output", path)  # 386 vertices
    return path


def test_user_story_solve_download_and_read_the_pressure_back(server, sphere_obj):
    with geomfit.Client(server.address) as client:
        mesh = client.upload_file(sphere_obj)
        residuals, final = [], None
        for event in client.membrane_solve(mesh.mesh_id, 2.0, **MATERIAL, send_displacement=True):
            if event.phase == "newton":
                residuals.append(event.values["residual"])
                assert event.counts["iteration"] >= 1 and "step" in event.values
            if event.phase == "stored":
                displacement = geomfit.client._decode(event.arrays[0].array, "<f8")
            final = event
        assert final.state == pb.JOB_STATE_SUCCEEDED
        assert 1 <= len(residuals) <= 6 and residuals[-1] <= 1e-10
        assert [(r.mesh_id, r.revision) for r in final.results] == [(mesh.mesh_id, 2)]

        positions, faces, info = client.download(mesh.mesh_id)
        assert info.revision == 2
        radius = np.linalg.norm(positions, axis=1)
        assert np.abs(radius - RADIUS).max() < 1e-3
        reference, _ = geomfit.read_mesh_file(sphere_obj)
        np.testing.assert_allclose(positions - displacement, reference, atol=1e-12)
        assert np.linalg.norm(displacement.mean(axis=0)) < 1e-12  # rigid modes removed

        # The pressure the deformed revision's stress balances: the one solved for. The
        # reference (revision 1) is no longer kept: its positions go with the request.
        x0 = reference
        p = client.membrane_pressure(mesh.mesh_id, deformed_revision=2, reference=x0, **MATERIAL)
        assert p.shape == (len(positions),)
        assert np.abs(p - 2).max() < 1e-2
        p_sent = client.membrane_pressure(mesh.mesh_id, positions, reference=x0, **MATERIAL)
        np.testing.assert_array_equal(p, p_sent)
        fields = client.membrane(mesh.mesh_id, positions, **MATERIAL, reference=x0,
                                 quantities=list(client.MEMBRANE_QUANTITIES))
        assert fields["stress"].shape == (len(positions), 3, 3) and fields["stretches"].shape == (len(positions), 2)
        assert np.abs(fields["stretches"] - RADIUS).max() < 1e-3
        assert np.abs(fields["traction"] + 2).max() < 2e-2


def test_bad_inputs_name_their_fields(server, sphere_obj):
    with geomfit.Client(server.address) as client:
        mesh = client.upload_file(sphere_obj)
        positions, _, _ = client.download(mesh.mesh_id)
        for kwargs, field in ((dict(young_modulus=100.0, poisson_ratio=0.5), "poisson_ratio"),
                              (dict(young_modulus=0.0, poisson_ratio=0.2), "young_modulus")):
            with pytest.raises(geomfit.GeomfitError) as e:
                client.membrane_pressure(mesh.mesh_id, positions, **kwargs)
            assert e.value.code == grpc.StatusCode.INVALID_ARGUMENT and field in e.value.details
        with pytest.raises(geomfit.GeomfitError) as e:
            client.membrane_pressure(mesh.mesh_id, positions[:-1], **MATERIAL)
        assert "deformed_positions" in e.value.details
        with pytest.raises(geomfit.GeomfitError) as e:
            next(client.membrane_solve(mesh.mesh_id, float("nan"), **MATERIAL))
        assert e.value.code == grpc.StatusCode.INVALID_ARGUMENT and "membrane.pressure" in e.value.details
        with pytest.raises(geomfit.GeomfitError) as e:  # Newton cut short: FAILED with its history
            list(client.membrane_solve(mesh.mesh_id, 2.0, **MATERIAL, max_iterations=1, max_load_cuts=0,
                                       tolerance=1e-15))
        assert e.value.code == grpc.StatusCode.FAILED_PRECONDITION and "residual history" in e.value.details
        assert client.get_mesh(mesh.mesh_id).revision == 1  # nothing stored


def read_vtp(path):
    reader = vtk.vtkXMLPolyDataReader()
    reader.SetFileName(path)
    reader.Update()
    out = reader.GetOutput()
    return vtk_to_numpy(out.GetPoints().GetData()), out.GetPointData()


def test_cli_solve_and_pressure_local_and_remote(server, sphere_obj, data_dir):
    material = ["--young-modulus", "100", "--poisson-ratio", "0.2"]
    local_obj = os.path.join(data_dir, "deformed.obj")
    r = cli("membrane", "solve", sphere_obj, "--local", *material, "--pressure", "2", "--output", local_obj)
    assert "iteration 1: residual" in r.stderr and "converged" in r.stderr, r.stderr
    remote_vtp = os.path.join(data_dir, "deformed.vtp")
    r = cli("membrane", "solve", sphere_obj, "--server", server.address, *material, "--pressure", "2", "--new-mesh",
            "--output", remote_vtp)
    assert "iteration 1: residual" in r.stderr and "SUCCEEDED" in r.stderr, r.stderr
    points, data = read_vtp(remote_vtp)
    assert np.abs(np.linalg.norm(points, axis=1) - RADIUS).max() < 1e-3
    displacement = vtk_to_numpy(data.GetArray("Displacement"))
    assert np.abs(np.linalg.norm(displacement, axis=1) - (RADIUS - 1)).max() < 1e-3
    local = np.loadtxt(local_obj, usecols=(1, 2, 3), comments=("#", "f"))
    np.testing.assert_allclose(local, points, atol=1e-9)  # the same solve in both modes

    for mode in (["--local"], ["--server", server.address]):
        table = os.path.join(data_dir, "pressure.tsv")
        r = cli("membrane", "pressure", sphere_obj, "--deformed", local_obj, *mode, *material,
                "--quantities", "pressure,von_mises", "--output", table, "--progress")
        lines = r.stderr.replace("\r", "\n").split("\n")
        for phase in ("fit", "membrane"):  # the library's phases, or the server's in its stream
            assert any(line.startswith(phase + " ") and "100%" in line for line in lines), (mode, r.stderr)
        p = np.loadtxt(table)
        assert p.shape == (len(points), 2)
        assert np.abs(p[:, 0] - 2).max() < 1e-2, mode
    r = cli("membrane", "solve", sphere_obj, "--local", *material, ok=False)
    assert r.returncode == 2 and "--pressure" in r.stderr
    r = cli("membrane", "pressure", sphere_obj, "--local", "--deformed", local_obj, "--young-modulus", "100",
            "--poisson-ratio", "0.5", ok=False)
    assert r.returncode == 2 and "--poisson-ratio" in r.stderr
