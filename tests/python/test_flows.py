"""Flows and operators from Python: client.flow as an iterator over job events with
snapshot revisions, a bad input naming its field, and the operators (CSR arrays, and
apply_operator equal to the matrix times the field)."""
import numpy as np
import pytest

import geomfit
from geomfit.v1 import geomfit_pb2 as pb

from conftest import torus


def test_flow_iterates_events_and_stores_revisions(server):
    with geomfit.Client(server.address) as client:
        positions, faces = torus(24, 12)
        mesh = client.upload(positions, faces, name="torus")
        events = list(client.flow(mesh.mesh_id, dt=1e-3, steps=6, snapshot_every=3, send_positions=True))
        steps = [e for e in events if e.phase == "step"]
        snapshots = [e for e in events if e.phase == "snapshot"]
        assert [e.step for e in steps] == list(range(1, 7))
        areas = [e.values["area"] for e in steps]
        assert all(b < a for a, b in zip(areas, areas[1:]))  # MCF decreases area
        assert [e.step for e in snapshots] == [3, 6]
        assert [e.results[0].revision for e in snapshots] == [mesh.revision + 1, mesh.revision + 2]
        assert events[-1].final and events[-1].state == pb.JOB_STATE_SUCCEEDED
        now, _, info = client.download(mesh.mesh_id)
        assert info.revision == mesh.revision + 2
        sent = np.frombuffer(snapshots[-1].arrays[0].array.data, "<f8").reshape(-1, 3)
        np.testing.assert_array_equal(sent, now)
        assert client.curvature(mesh.mesh_id, degree=2).mean.shape == (len(positions),)


def test_flow_bad_input_names_the_field(server):
    with geomfit.Client(server.address) as client:
        positions, faces = torus(24, 12)
        mesh = client.upload(positions, faces, name="torus")
        with pytest.raises(geomfit.GeomfitError) as e:
            next(client.flow(mesh.mesh_id, dt=-1.0, steps=3))
        assert "flow.dt" in str(e.value.details)
        with pytest.raises(geomfit.GeomfitError) as e:
            next(client.flow(mesh.mesh_id, dt=1e-3, steps=3, scheme="leapfrog"))
        assert "flow.scheme" in str(e.value.details)
        for bad in (-1e-3, float("nan"), float("inf")):
            with pytest.raises(geomfit.GeomfitError) as e:
                next(client.flow(mesh.mesh_id, dt=1e-3, steps=3, time_tolerance=bad))
            assert "flow.time_tolerance" in str(e.value.details)


def test_flow_time_tolerance_zero_agrees_with_the_default(server):
    # 0: every solve to 1e-12; unset: solves tied to the step's local error dt^2 = 1e-6.
    with geomfit.Client(server.address) as client:
        positions, faces = torus(24, 12)
        ends = []
        for i, options in enumerate(({"time_tolerance": 0.0}, {})):
            mesh = client.upload(positions, faces, name="torus %d" % i)  # a fresh mesh id per run
            events = list(client.flow(mesh.mesh_id, dt=1e-3, steps=6, **options))
            assert events[-1].state == pb.JOB_STATE_SUCCEEDED
            ends.append(client.download(mesh.mesh_id)[0])
        assert np.abs(ends[0] - ends[1]).max() < 0.1 * 1e-3 ** 2


def test_operator_and_apply_operator(server):
    with geomfit.Client(server.address) as client:
        positions, faces = torus(32, 16)
        mesh = client.upload(positions, faces, name="torus")
        n = len(positions)
        L = client.operator(mesh.mesh_id, "laplace_beltrami", degree=4)
        if isinstance(L, tuple):  # no scipy: CSR arrays
            offsets, columns, values, shape = L
            assert shape == (n, n) and offsets.shape == (n + 1,) and offsets[-1] == len(columns) == len(values)
            rows = np.repeat(np.arange(n), np.diff(offsets))
            matvec = lambda x: np.bincount(rows, weights=values * x[columns], minlength=n)
        else:
            assert L.shape == (n, n)
            matvec = lambda x: L @ x
        x = positions[:, 0].copy()
        Lx = client.apply_operator(mesh.mesh_id, x, "laplace_beltrami", degree=4)
        assert Lx.shape == (n, 1)
        np.testing.assert_allclose(Lx[:, 0], matvec(x), rtol=1e-12, atol=1e-9)
        assert np.abs(client.apply_operator(mesh.mesh_id, np.ones(n))).max() < 1e-8  # L 1 = 0
        assert client.apply_operator(mesh.mesh_id, x, "gradient").shape == (n, 3)
        with pytest.raises(geomfit.GeomfitError) as e:
            client.apply_operator(mesh.mesh_id, np.ones(n - 1))
        assert "field" in e.value.details
        with pytest.raises(ValueError):
            client.operator(mesh.mesh_id, "curl")


def test_operator_is_a_scipy_matrix_equal_to_the_csr_arrays(server, monkeypatch):
    """With scipy (python3-scipy, installed by scripts/install-deps.sh) client.operator
    returns a scipy.sparse CSR matrix; without it, the numpy CSR arrays: the same matrix."""
    import sys

    import scipy.sparse
    with geomfit.Client(server.address) as client:
        positions, faces = torus(24, 12)
        mesh = client.upload(positions, faces, name="torus")
        n = len(positions)
        for name, shape in [("laplace_beltrami", (n, n)), ("gradient", (3 * n, n)), ("divergence", (n, 3 * n))]:
            m = client.operator(mesh.mesh_id, name, degree=3)
            assert scipy.sparse.issparse(m) and m.format == "csr" and m.shape == shape
            with monkeypatch.context() as patch:  # scipy not importable: the numpy fallback
                patch.setitem(sys.modules, "scipy", None)
                patch.setitem(sys.modules, "scipy.sparse", None)
                offsets, columns, values, arrays_shape = client.operator(mesh.mesh_id, name, degree=3)
            assert arrays_shape == shape
            np.testing.assert_array_equal(m.indptr, offsets)
            np.testing.assert_array_equal(m.indices, columns)
            np.testing.assert_array_equal(m.data, values)
            dense = np.zeros(shape)
            rows = np.repeat(np.arange(shape[0]), np.diff(offsets))
            dense[rows, columns] = values
            np.testing.assert_array_equal(m.toarray(), dense)
        L = client.operator(mesh.mesh_id, "laplace_beltrami", degree=3)
        np.testing.assert_allclose(L @ np.ones(n), 0, atol=1e-8)  # L 1 = 0, through scipy
