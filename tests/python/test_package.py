"""The geomfit package as users meet it: version, readers of every format, input checks,
picklable errors, compact reprs, docstrings, meshio interop, job progress callbacks."""
import inspect
import os
import pickle
import subprocess

import grpc
import numpy as np
import pytest

import geomfit
from geomfit import readers
from conftest import torus

CLI = os.environ.get("GEOMFIT_CLI_BINARY")


def cli(*args):
    subprocess.run([CLI, *args], check=True, stdout=subprocess.DEVNULL)


def test_version_is_the_projects():
    assert geomfit.__version__ == os.environ["GEOMFIT_PROJECT_VERSION"]


def test_error_pickles_with_code_and_details():
    e = geomfit.GeomfitError(grpc.StatusCode.NOT_FOUND, "mesh m-1 not found")
    back = pickle.loads(pickle.dumps(e))
    assert type(back) is geomfit.GeomfitError
    assert back.code == grpc.StatusCode.NOT_FOUND and back.details == "mesh m-1 not found"
    assert str(back) == "NOT_FOUND: mesh m-1 not found"


def test_faces_must_be_integers(server):
    positions, faces = torus(8, 6)
    with geomfit.Client(server.address) as c:
        bad = faces.astype(np.float64)
        bad[5, 1] = 2.7
        with pytest.raises(ValueError, match="face 5 holds 2.7"):
            c.upload(positions, bad)
        with pytest.raises(ValueError, match="integers"):
            c.upload(positions, faces.astype(str))
        with pytest.raises(ValueError, match="-1 padding"):
            c.upload(positions, faces - 2)
        # Integral floats (a TSV read by numpy) are integers.
        assert c.upload(positions, faces.astype(np.float64)).mesh_id == c.upload(positions, faces).mesh_id


def _write_ascii_ply(path, positions, faces):
    with open(path, "w") as f:
        f.write("ply\nformat ascii 1.0\nelement vertex %d\nproperty double x\nproperty double y\n"
                "property double z\nproperty uchar red\nelement face %d\nproperty list uchar int vertex_indices\n"
                "end_header\n" % (len(positions), len(faces)))
        for p in positions:
            f.write("%.17g %.17g %.17g 7\n" % tuple(p))
        for t in faces:
            k = 3 if t[-1] < 0 else len(t)
            f.write("%d %s\n" % (k, " ".join(str(i) for i in t[:k])))


def _write_ascii_stl(path, positions, faces):
    with open(path, "w") as f:
        f.write("solid t\n")
        for t in faces:
            f.write("facet normal 0 0 0\nouter loop\n")
            for i in t:
                f.write("vertex %.9g %.9g %.9g\n" % tuple(np.float32(positions[i])))
            f.write("endloop\nendfacet\n")
        f.write("endsolid t\n")


@pytest.mark.parametrize("shape", ["torus", "quadtorus"])
def test_every_format_reads_alike_natively_and_with_numpy(tmp_path, shape, server):
    """OBJ, OFF, PLY ascii/binary, STL ascii/binary: the C++ readers (through
    geomfit._native) and the numpy readers return identical arrays, equal to the OBJ's
    (STL: float32 coordinates, corners welded in order of appearance)."""
    obj = str(tmp_path / "m.obj")
    cli("generate", shape, "--level", "4", "--output", obj)
    positions, faces = readers.read_mesh_file(obj, native=False)
    assert faces.shape[1] == (4 if shape == "quadtorus" else 3)
    files = {}
    for ext in ("off", "ply", "stl"):
        files[ext] = str(tmp_path / ("m." + ext))
        cli("convert", obj, files[ext])
    files["ascii.ply"] = str(tmp_path / "a.ply")
    _write_ascii_ply(files["ascii.ply"], positions, faces)
    tris = faces if faces.shape[1] == 3 else faces[:, [0, 1, 2, 0, 2, 3]].reshape(-1, 3)  # quads split 0-2
    files["ascii.stl"] = str(tmp_path / "a.stl")
    _write_ascii_stl(files["ascii.stl"], positions, tris)
    for name, path in files.items():
        p_np, f_np = readers.read_mesh_file(path, native=False)
        if readers._native is not None:
            p_cc, f_cc = readers.read_mesh_file(path)
            np.testing.assert_array_equal(p_np, p_cc, err_msg=name)
            np.testing.assert_array_equal(f_np, f_cc, err_msg=name)
        if name.endswith("stl"):
            assert len(p_np) == len(positions) and f_np.shape == tris.shape, name
            np.testing.assert_allclose(p_np[f_np], positions[tris], rtol=0, atol=1e-6, err_msg=name)
        else:
            np.testing.assert_array_equal(p_np, positions, err_msg=name)
            np.testing.assert_array_equal(f_np, faces, err_msg=name)
    with geomfit.Client(server.address) as c:
        mesh_ids = {c.upload_file(files[k], name="m").mesh_id for k in ("off", "ply", "ascii.ply")}
        assert mesh_ids == {c.upload_file(obj, name="m").mesh_id}
        assert c.upload_file(files["stl"]).num_faces == len(tris)


def test_reader_errors_name_the_file(tmp_path):
    bad = tmp_path / "bad.off"
    bad.write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 5\n")
    for native in (True, False):
        with pytest.raises(ValueError, match="bad.off"):
            readers.read_mesh_file(str(bad), native=native)
    with pytest.raises(ValueError, match="unknown mesh format"):
        readers.read_mesh_file(str(tmp_path / "x.vtk"))


def test_repr_is_compact(server, torus_mesh):
    positions, faces = torus_mesh
    with geomfit.Client(server.address) as c:
        d = c.curvature(c.upload(positions, faces).mesh_id, degree=3, diagnostics=True)
    text = repr(d)
    assert len(text) < 250, text
    assert text.startswith("Differentials(mesh_id='m-") and "mean[%d]" % len(positions) in text


def test_every_public_method_has_a_docstring():
    missing = []
    for name, obj in vars(geomfit).items():
        if name.startswith("_") or not (inspect.isclass(obj) or inspect.isfunction(obj)):
            continue
        if not inspect.getdoc(obj):
            missing.append(name)
        if inspect.isclass(obj):
            for attr, member in vars(obj).items():
                if (not attr.startswith("_") or attr in ("__enter__", "__exit__")) and callable(member) \
                        and not inspect.getdoc(member):
                    missing.append("%s.%s" % (name, attr))
    assert not missing


def test_package_is_typed():
    assert os.path.isfile(os.path.join(os.path.dirname(geomfit.client.__file__), "py.typed"))
    hints = inspect.signature(geomfit.Client.curvature)
    assert hints.return_annotation is geomfit.Differentials


def test_meshio_round_trip(tmp_path, server, torus_mesh):
    meshio = pytest.importorskip("meshio")
    positions, faces = torus_mesh
    with geomfit.Client(server.address) as c:
        d = c.curvature(c.upload(positions, faces).mesh_id, degree=4)
    m = geomfit.to_meshio(positions, faces, differentials=d, point_data={"id": np.arange(len(positions))})
    path = str(tmp_path / "t.vtu")
    m.write(path)
    back = meshio.read(path)
    p, f = geomfit.from_meshio(back)
    np.testing.assert_array_equal(p, positions)
    np.testing.assert_array_equal(f, faces)
    np.testing.assert_array_equal(back.point_data["MeanCurvature"], d.mean)
    # Mixed meshes keep -1 padding both ways.
    mixed = np.array([[0, 1, 2, -1], [1, 3, 4, 2]], dtype=np.int32)
    p, f = geomfit.from_meshio(geomfit.to_meshio(np.random.rand(5, 3), mixed))
    np.testing.assert_array_equal(f, mixed)
    with pytest.raises(ValueError, match="no triangle or quad"):
        geomfit.from_meshio(meshio.Mesh(p, [("line", np.array([[0, 1]]))]))


def test_wait_job_reports_progress(server):
    positions, faces = torus(12, 8)
    seen = []
    with geomfit.Client(server.address) as c:
        job = c.refine_job(c.upload(positions, faces).mesh_id, levels=2)
        final = c.wait_job(job.job_id, progress=seen.append)
    assert final.final and final.state == geomfit.client.pb.JOB_STATE_SUCCEEDED
    assert [e.seq for e in seen] == list(range(1, len(seen) + 1))
    assert seen[-1] is final and len(final.results) == 2
    assert {e.step for e in seen} >= {1, 2}


def test_progress_callbacks_draw_tqdm_bars_and_text(server, capsys):
    import io

    import geomfit.progress
    positions, faces = torus(12, 8)
    text = io.StringIO()
    with geomfit.Client(server.address) as c:
        mesh_id = c.upload(positions, faces).mesh_id
        final = c.wait_job(c.refine_job(mesh_id, levels=2).job_id, progress=geomfit.progress.tqdm_callback())
        c.wait_job(c.refine_job(mesh_id, levels=1).job_id, progress=geomfit.progress.text_callback(text))
    assert len(final.results) == 2
    bars = capsys.readouterr().err
    assert "refine 1" in bars and "refine 2" in bars, bars  # a tqdm bar per (step, phase)
    lines = text.getvalue().splitlines()
    assert lines[0].endswith(": 1 queued step 0 0"), lines
    assert any(line.endswith(" stored step 1 1/1") for line in lines), lines
