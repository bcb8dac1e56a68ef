"""The native transport (geomfit._native, the C++ client) against grpcio, on the real server."""
import grpc
import numpy as np
import pytest

import geomfit
from geomfit import _native
from conftest import torus

ALL_QUANTITIES = list(geomfit.QUANTITIES)


def test_transport_selection():
    assert geomfit.Client("127.0.0.1:1", transport="native").transport == "native"  # the module is built
    assert geomfit.Client("127.0.0.1:1").transport == "native"
    assert geomfit.Client("127.0.0.1:1", transport="grpcio").transport == "grpcio"
    with pytest.raises(ValueError):
        geomfit.Client("127.0.0.1:1", transport="bogus")


def _without(message, *fields):
    copy = type(message)()
    copy.CopyFrom(message)
    for f in fields:
        copy.ClearField(f)
    return copy


def test_transports_give_identical_results(server):
    positions, faces = torus(96, 48)
    with geomfit.Client(server.address, transport="native") as native, \
            geomfit.Client(server.address, transport="grpcio") as grpcio:
        mesh_id = grpcio.upload(positions, faces).mesh_id
        moved = 1.5 * positions

        # A fresh revision: the native call computes (several chunks), grpcio's finds it cached.
        info = native.update_positions(mesh_id, moved, expected_revision=1)
        assert info == native.get_mesh(mesh_id)
        a = native.curvature(mesh_id, degree=3, quantities=ALL_QUANTITIES, diagnostics=True)
        b = grpcio.curvature(mesh_id, degree=3, quantities=ALL_QUANTITIES, diagnostics=True)
        assert not a.summary.fit_cache_hit and b.summary.quantities_cache_hit
        assert sum(a.summary.vertices_by_degree) == len(positions)  # the last chunk's summary
        timing = ("fit_cache_hit", "quantities_cache_hit", "fit_ms", "evaluate_ms", "joined_compute_ms")
        assert _without(a.summary, *timing) == _without(b.summary, *timing)
        for name in ("normals", "mean", "gaussian", "k1", "k2", "dir1", "dir2", "tensor"):
            x, y = getattr(a, name), getattr(b, name)
            assert x.dtype == y.dtype == np.float64 and x.shape == y.shape, name
            assert x.flags.c_contiguous and x.flags.writeable, name
            assert np.array_equal(x, y), name
        assert a.tensor.shape == (len(positions), 9)
        assert a.diagnostics.keys() == b.diagnostics.keys() == {"points", "degree_used", "flags", "condition"}
        for name, x in a.diagnostics.items():
            assert x.dtype == b.diagnostics[name].dtype and np.array_equal(x, b.diagnostics[name]), name
        # Both cached: the summaries are the same in every field.
        c = native.curvature(mesh_id, degree=3, quantities=ALL_QUANTITIES, diagnostics=True)
        assert c.summary == grpcio.curvature(mesh_id, degree=3, quantities=ALL_QUANTITIES, diagnostics=True).summary

        # Only what was asked for.
        d = native.curvature(mesh_id, quantities=["mean"])
        assert d.mean is not None and d.normals is None and d.k1 is None and d.diagnostics is None
        np.testing.assert_array_equal(d.mean, grpcio.curvature(mesh_id, quantities=["mean"]).mean)

        # The same update through each: the same MeshInfo but for revision and time.
        again = grpcio.update_positions(mesh_id, moved, expected_revision=2)
        assert again.revision == 3
        assert _without(info, "revision", "updated_unix_ms") == _without(again, "revision", "updated_unix_ms")
        # Any float64 layout is accepted (copied when not C-contiguous).
        strided = np.asfortranarray(moved)
        assert native.update_positions(mesh_id, strided, expected_revision=3).revision == 4
        back, _, _ = grpcio.download(mesh_id)
        assert back.tobytes() == moved.tobytes()
        calls = {m.method: m.count for m in grpcio.statistics().methods}
        assert calls.get("SetPositions") == 3 and "UpdatePositions" not in calls


def _fails(code, call, text=""):
    with pytest.raises(geomfit.GeomfitError) as e:
        call()
    assert e.value.code == code and text in e.value.details, e.value


def test_native_bad_input(server, torus_mesh):
    positions, faces = torus_mesh
    with geomfit.Client(server.address, transport="native") as client:
        info = client.upload(positions, faces)
        nan = positions.copy()
        nan[9, 1] = np.nan
        _fails(grpc.StatusCode.NOT_FOUND, lambda: client.update_positions("m-unknown", positions), "m-unknown")
        _fails(grpc.StatusCode.NOT_FOUND, lambda: client.curvature("m-unknown"), "m-unknown")
        _fails(grpc.StatusCode.INVALID_ARGUMENT, lambda: client.update_positions(info.mesh_id, nan), "vertex 9")
        _fails(grpc.StatusCode.ABORTED,
               lambda: client.update_positions(info.mesh_id, 2.0 * positions, expected_revision=7))
        _fails(grpc.StatusCode.INVALID_ARGUMENT, lambda: client.update_positions(info.mesh_id, positions[:-1]))
        _fails(grpc.StatusCode.INVALID_ARGUMENT, lambda: client.curvature(info.mesh_id, degree=12), "degree")
        for shape in ((len(positions), 2), (len(positions) * 3,), (len(positions), 3, 1)):
            with pytest.raises(ValueError):
                client.update_positions(info.mesh_id, np.zeros(shape))
        with pytest.raises(ValueError):
            client.curvature(info.mesh_id, quantities=["mean", "torsion"])
        with pytest.raises(ValueError):
            client.curvature(info.mesh_id, method="spline")

        # The module by itself: shapes checked, failures as RpcError(code, details).
        raw = _native.Client(server.address, 10.0, 1, 0.1, 64 << 20)
        with pytest.raises(ValueError):
            raw.set_positions(info.mesh_id, np.zeros((4, 2)))
        with pytest.raises(_native.RpcError) as e:
            raw.set_positions("m-unknown", positions, 1)
        assert e.value.args[0] == grpc.StatusCode.NOT_FOUND.value[0] and "m-unknown" in e.value.args[1]
        with pytest.raises(ValueError):
            raw.compute(b"\xff\xff")

        # The server is healthy and the mesh as uploaded.
        assert client.server_info().api_version == "geomfit.v1"
        assert client.get_mesh(info.mesh_id).revision == 1
        back, _, _ = client.download(info.mesh_id)
        assert back.tobytes() == positions.tobytes()
        assert client.curvature(info.mesh_id, quantities=["mean"]).summary.revision == 1
        assert client.update_positions(info.mesh_id, 2.0 * positions, expected_revision=1).revision == 2
