"""`geomfit flow --server ... --output-series PREFIX` writes a .pvd time series whose
.vtp snapshots VTK reads back (python3-vtk9): the first frame is the input, the last
the mesh's final revision on the server; `geomfit operator` writes Matrix Market."""
import os
import subprocess
import xml.etree.ElementTree as ET

import numpy as np

import geomfit
import vtk  # noqa: E402  (python3-vtk9, installed by scripts/install-deps.sh)
from vtk.util.numpy_support import vtk_to_numpy  # noqa: E402

from conftest import torus

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def cli(*args):
    binary = os.environ.get("GEOMFIT_CLI_BINARY")
    assert binary and os.path.exists(binary), "GEOMFIT_CLI_BINARY must name the geomfit binary"
    r = subprocess.run([binary, *args], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, "geomfit %s failed (%d): %s" % (" ".join(args), r.returncode, r.stderr)
    return r


def read_vtp(path):
    reader = vtk.vtkXMLPolyDataReader()
    reader.SetFileName(path)
    reader.Update()
    out = reader.GetOutput()
    return vtk_to_numpy(out.GetPoints().GetData()), out.GetNumberOfPolys()


def test_flow_writes_a_pvd_series(server, data_dir):
    torus_obj = os.path.join(REPO, "data", "torus.obj")
    prefix = os.path.join(data_dir, "mcf")
    r = cli("flow", torus_obj, "--server", server.address, "--dt", "1e-3", "--steps", "4", "--snapshot-every", "2",
            "--degree", "3", "--output-series", prefix)
    assert r.stderr.count("geomfit: step ") == 4, r.stderr
    assert "SUCCEEDED" in r.stderr
    root = ET.parse(prefix + ".pvd").getroot()
    sets = root.find("Collection").findall("DataSet")
    assert [float(s.get("timestep")) for s in sets] == [0.0, 2e-3, 4e-3]
    frames = [read_vtp(os.path.join(data_dir, s.get("file"))) for s in sets]
    with geomfit.Client(server.address) as client:
        mesh = [m for m in client.list_meshes()][0]
        final, faces, info = client.download(mesh.mesh_id)
    assert info.revision == mesh.revision
    points0, polys0 = frames[0]
    assert polys0 == len(faces) and len(points0) == len(final)
    np.testing.assert_array_equal(frames[-1][0], final)  # the last frame is the stored revision
    assert np.abs(frames[1][0] - points0).max() > 0  # it moved


def test_flow_local_and_operator(server, data_dir):
    torus_obj = os.path.join(REPO, "data", "torus.obj")
    prefix = os.path.join(data_dir, "local")
    r = cli("flow", torus_obj, "--local", "--dt", "1e-3", "--steps", "2", "--degree", "3", "--output-series", prefix)
    assert r.stderr.count("geomfit: step ") == 2, r.stderr
    sets = ET.parse(prefix + ".pvd").getroot().find("Collection").findall("DataSet")
    assert len(sets) == 3
    mtx = os.path.join(data_dir, "L.mtx")
    cli("operator", torus_obj, "--server", server.address, "--operator", "laplace_beltrami", "--output", mtx)
    lines = open(mtx).read().splitlines()
    assert lines[0].startswith("%%MatrixMarket matrix coordinate real general")
    rows, cols, nnz = map(int, lines[1].split())
    assert rows == cols and nnz == len(lines) - 2
    # Rows of L sum to zero (L 1 = 0).
    sums = np.zeros(rows)
    for line in lines[2:]:
        i, j, v = line.split()
        sums[int(i) - 1] += float(v)
    assert np.abs(sums).max() < 1e-8
