"""VTK files written by `geomfit` read back with VTK's own XML readers (python3-vtk9)
and, for .vtu, with meshio (python3-meshio): geometry, cells, array types, active
normals and scalars, and values bit-identical to the TSV output."""
import os
import subprocess

import numpy as np
import pytest

import vtk  # noqa: E402  (python3-vtk9, installed by scripts/install-deps.sh)
import meshio  # noqa: E402
from vtk.util.numpy_support import vtk_to_numpy  # noqa: E402


def cli():
    binary = os.environ.get("GEOMFIT_CLI_BINARY")
    if not binary or not os.path.exists(binary):
        raise RuntimeError("GEOMFIT_CLI_BINARY must name the geomfit binary")
    return binary


def run(*args):
    r = subprocess.run([cli(), *args], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, "geomfit %s failed (%d): %s" % (" ".join(args), r.returncode, r.stderr)
    return r


def read_obj(path):
    v, f = [], []
    for line in open(path):
        t = line.split()
        if t and t[0] == "v":
            v.append([float(x) for x in t[1:4]])
        elif t and t[0] == "f":
            f.append([int(x) - 1 for x in t[1:]])
    return np.array(v), f


def read_vtk(path):
    reader = vtk.vtkXMLPolyDataReader() if path.endswith(".vtp") else vtk.vtkXMLUnstructuredGridReader()
    reader.SetFileName(path)
    reader.Update()
    assert reader.GetErrorCode() == 0, path
    return reader.GetOutput()


def cells_of(data):
    """Point ids of every polygon (vtp) or cell (vtu)."""
    out = []
    for c in range(data.GetNumberOfCells()):
        ids = data.GetCell(c).GetPointIds()
        out.append([ids.GetId(i) for i in range(ids.GetNumberOfIds())])
    return out


@pytest.fixture(scope="module")
def case(tmp_path_factory):
    d = tmp_path_factory.mktemp("vtk")
    mesh = str(d / "q.obj")
    # quadtorus: quads, so both cell types' offsets are exercised with triangles below.
    run("generate", "quadtorus", "--level", "6", "--output", mesh)
    tsv = str(d / "q.tsv")
    run("curvature", "--local", mesh, "--degree", "3", "--output", tsv)
    table = np.loadtxt(tsv, ndmin=2)  # the header starts with #
    return d, mesh, table


ENCODING_FLAGS = {"bin": [], "ascii": ["--ascii"], "zlib": ["--zlib"]}


@pytest.mark.parametrize("ext", ["vtp", "vtu"])
@pytest.mark.parametrize("encoding", ["bin", "ascii", "zlib"])
def test_vtk_reads_curvature_output(case, ext, encoding):
    d, mesh, table = case
    ascii = encoding == "ascii"
    out = str(d / ("c_%s.%s" % (encoding, ext)))
    run("curvature", "--local", mesh, "--degree", "3", "--output", out, *ENCODING_FLAGS[encoding])
    head = open(out, "rb").read(400)
    assert (b'format="ascii"' in open(out, "rb").read()) == ascii
    assert (b"header_type=\"UInt64\"" in head) == (not ascii)
    assert (b'compressor="vtkZLibDataCompressor"' in head) == (encoding == "zlib")

    data = read_vtk(out)
    points, faces = read_obj(mesh)
    assert data.GetNumberOfPoints() == len(points)
    assert data.GetNumberOfCells() == len(faces)
    np.testing.assert_array_equal(vtk_to_numpy(data.GetPoints().GetData()), points)
    assert cells_of(data) == faces
    if ext == "vtu":
        types = {data.GetCellType(c) for c in range(data.GetNumberOfCells())}
        assert types == {vtk.VTK_QUAD}

    pd = data.GetPointData()
    assert pd.GetNormals() is not None and pd.GetNormals().GetName() == "Normals"
    assert pd.GetScalars() is not None and pd.GetScalars().GetName() == "MeanCurvature"
    names = [pd.GetArrayName(i) for i in range(pd.GetNumberOfArrays())]
    assert names == ["Normals", "MeanCurvature", "GaussianCurvature", "k1", "k2", "Direction1",
                     "Direction2", "CurvatureTensor", "DegreeUsed", "StencilPoints", "Flags"]
    assert "Points" not in names
    expect_type = {"DegreeUsed": vtk.VTK_INT, "StencilPoints": vtk.VTK_INT, "Flags": vtk.VTK_UNSIGNED_CHAR}
    for n in names:
        assert pd.GetArray(n).GetDataType() == expect_type.get(n, vtk.VTK_DOUBLE), n

    def arr(n):
        return vtk_to_numpy(pd.GetArray(n))

    # Bit-identical to the TSV (%.17g round-trips doubles exactly).
    np.testing.assert_array_equal(arr("Normals"), table[:, 0:3])
    np.testing.assert_array_equal(arr("MeanCurvature"), table[:, 3])
    np.testing.assert_array_equal(arr("GaussianCurvature"), table[:, 4])
    np.testing.assert_array_equal(arr("Direction1"), table[:, 7:10])
    np.testing.assert_array_equal(arr("DegreeUsed"), table[:, 13])
    np.testing.assert_array_equal(arr("StencilPoints"), table[:, 14])
    np.testing.assert_array_equal(arr("Flags"), table[:, 15])
    assert arr("CurvatureTensor").shape == (len(points), 9)


def test_binary_is_much_smaller_than_ascii(case):
    d, _, _ = case
    run("curvature", "--local", case[1], "--degree", "3", "--output", str(d / "s.vtp"))
    run("curvature", "--local", case[1], "--degree", "3", "--output", str(d / "s_ascii.vtp"), "--ascii")
    assert os.path.getsize(str(d / "s.vtp")) * 2 < os.path.getsize(str(d / "s_ascii.vtp"))
    # Flags, degrees and stencil sizes repeat: compressed is smaller still.
    run("curvature", "--local", case[1], "--degree", "3", "--output", str(d / "s_zlib.vtp"), "--zlib")
    assert os.path.getsize(str(d / "s_zlib.vtp")) < os.path.getsize(str(d / "s.vtp"))


def test_ascii_and_zlib_exclude_each_other(case):
    d, mesh, _ = case
    r = subprocess.run([cli(), "curvature", "--local", mesh, "--output", str(d / "x.vtp"), "--ascii", "--zlib"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "--ascii and --zlib" in r.stderr, r.stderr
    assert not os.path.exists(str(d / "x.vtp"))


@pytest.mark.parametrize("encoding", ["bin", "ascii", "zlib"])
def test_meshio_reads_vtu(case, encoding):
    d, mesh, table = case
    out = str(d / ("m_%s.vtu" % encoding))
    run("curvature", "--local", mesh, "--degree", "3", "--output", out, *ENCODING_FLAGS[encoding])
    m = meshio.read(out)
    points, faces = read_obj(mesh)
    np.testing.assert_array_equal(m.points, points)
    assert [b.type for b in m.cells] == ["quad"]
    np.testing.assert_array_equal(m.cells[0].data, np.array(faces))
    np.testing.assert_array_equal(m.point_data["MeanCurvature"].ravel(), table[:, 3])
    np.testing.assert_array_equal(m.point_data["Normals"], table[:, 0:3])
    assert m.point_data["Flags"].dtype == np.uint8
    assert m.point_data["DegreeUsed"].dtype == np.int32


@pytest.mark.parametrize("level", [5, 6, 7, 8, 9, 10, 11, 12])
def test_converted_meshes_read_back(tmp_path, level):
    """convert writes .vtp/.vtu without point data; triangles; sizes vary so the
    appended blocks' offsets take many values."""
    obj = str(tmp_path / "t.obj")
    run("generate", "torus", "--level", str(level), "--output", obj)
    points, faces = read_obj(obj)
    for flags in ([], ["--zlib"]):
        for ext in ("vtp", "vtu"):
            out = str(tmp_path / ("t." + ext))
            run("convert", obj, out, *flags)
            data = read_vtk(out)
            np.testing.assert_array_equal(vtk_to_numpy(data.GetPoints().GetData()), points)
            assert cells_of(data) == faces
        m = meshio.read(str(tmp_path / "t.vtu"))
        np.testing.assert_array_equal(m.points, points)
        np.testing.assert_array_equal(m.cells_dict["triangle"], np.array(faces))


def test_zlib_array_of_whole_blocks(tmp_path):
    """4096 points are 3 x 32 KiB of Float64: the last compressed block is full (the
    header's last-block size is 0)."""
    n = 64
    obj = str(tmp_path / "grid.obj")
    with open(obj, "w") as f:
        for j in range(n):
            for i in range(n):
                f.write("v %.17g %.17g %.17g\n" % (i / n, j / n, 0.1 * np.sin(i + j)))
        for j in range(n - 1):
            for i in range(n - 1):
                a = j * n + i + 1
                f.write("f %d %d %d\nf %d %d %d\n" % (a, a + 1, a + n + 1, a, a + n + 1, a + n))
    points, faces = read_obj(obj)
    assert len(points) * 24 == 3 * 32768
    out = str(tmp_path / "grid.vtp")
    run("convert", obj, out, "--zlib")
    data = read_vtk(out)
    np.testing.assert_array_equal(vtk_to_numpy(data.GetPoints().GetData()), points)
    assert cells_of(data) == faces


def test_mixed_triangles_and_quads(tmp_path):
    """A strip of quads and triangles: per-cell sizes and VTK cell types line up."""
    obj = str(tmp_path / "mixed.obj")
    with open(obj, "w") as f:
        f.write("v 0 0 0\nv 1 0 0.125\nv 2 0 0\nv 0 1 0\nv 1 1 -0.5\nv 2 1 0\nv 3 0.5 0\n"
                "f 1 2 5 4\nf 2 3 6\nf 2 6 5\nf 3 7 6\n")
    points, faces = read_obj(obj)
    for ext in ("vtp", "vtu"):
        out = str(tmp_path / ("mixed." + ext))
        run("convert", obj, out)
        data = read_vtk(out)
        assert cells_of(data) == faces
        if ext == "vtu":
            assert [data.GetCellType(c) for c in range(4)] == [vtk.VTK_QUAD] + [vtk.VTK_TRIANGLE] * 3
    m = meshio.read(str(tmp_path / "mixed.vtu"))
    assert {b.type: len(b.data) for b in m.cells} == {"quad": 1, "triangle": 3}


@pytest.mark.parametrize("order", [2, 3])
def test_nodes_vtu_is_lagrange_cells_in_vtk_order(tmp_path, order):
    """`geomfit nodes` on a flat, non-uniform grid of quads and triangles: the surface is
    the plane, so every node must sit where VTK's own parametric coordinates of that
    node put it on the cell's bilinear (quad) or linear (triangle) map. Nodes in another
    order than VTK's (e.g. quad edges 2-3 and 3-0 not reversed at order 3) miss by the
    node spacing."""
    rng = np.random.default_rng(3)
    xs, ys = [0, 0.9, 2.1, 2.9, 4.2], [0, 1.1, 1.9, 3.2]
    verts = [(x + 0.1 * rng.random(), y + 0.1 * rng.random(), 0.0) for y in ys for x in xs]
    faces = []
    for j in range(3):
        for i in range(4):
            a = j * 5 + i
            b, c, d = a + 1, a + 6, a + 5
            faces += [(a, b, c, d)] if (i + j) % 2 else [(a, b, c), (a, c, d)]
    obj = str(tmp_path / "grid.obj")
    with open(obj, "w") as f:
        f.writelines("v %r %r %r\n" % v for v in verts)
        f.writelines("f %s\n" % " ".join(str(x + 1) for x in face) for face in faces)
    prefix = str(tmp_path / "grid")
    run("nodes", obj, "--order", str(order), "--output", prefix)
    g = read_vtk(prefix + ".vtu")
    assert g.GetNumberOfCells() == len(faces)
    nodes = vtk_to_numpy(g.GetPoints().GetData())
    expect_n = {vtk.VTK_LAGRANGE_TRIANGLE: (order + 1) * (order + 2) // 2,
                vtk.VTK_LAGRANGE_QUADRILATERAL: (order + 1) ** 2}
    worst = 0.0
    for c in range(g.GetNumberOfCells()):
        cell, kind = g.GetCell(c), g.GetCellType(c)
        assert kind == (vtk.VTK_LAGRANGE_TRIANGLE if len(faces[c]) == 3 else vtk.VTK_LAGRANGE_QUADRILATERAL)
        n = cell.GetNumberOfPoints()
        assert n == expect_n[kind]
        x = nodes[[cell.GetPointId(i) for i in range(n)]]
        np.testing.assert_array_equal(x[:len(faces[c])], np.array(verts)[list(faces[c])])
        pc = cell.GetParametricCoords()
        for i in range(n):
            r, s = pc[3 * i], pc[3 * i + 1]
            if kind == vtk.VTK_LAGRANGE_TRIANGLE:
                want = (1 - r - s) * x[0] + r * x[1] + s * x[2]
            else:
                want = (1 - r) * (1 - s) * x[0] + r * (1 - s) * x[1] + r * s * x[2] + (1 - r) * s * x[3]
            worst = max(worst, float(np.abs(want - x[i]).max()))
    assert worst < 1e-12, worst
