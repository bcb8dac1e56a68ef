"""The Python client against the real geomfit-server binary."""
import os
import signal

import grpc
import numpy as np
import pytest

import geomfit
from conftest import ServerProcess, torus


def exact_torus_mean(positions, R=1.0, r=0.3):
    """H of the torus at points on it (outward normal; +1/R convention)."""
    rho = np.hypot(positions[:, 0], positions[:, 1])
    cos_v = (rho - R) / r
    return (R + 2 * r * cos_v) / (2 * r * (R + r * cos_v))


def test_upload_curvature_update_download(server, torus_mesh, transport):
    positions, faces = torus_mesh
    with geomfit.Client(server.address, chunk_rows=100, transport=transport) as client:
        info = client.upload(positions, faces, name="torus", labels={"k": "v"})
        assert info.revision == 1
        assert info.num_vertices == len(positions)
        assert client.upload(positions, faces, name="torus", labels={"k": "v"}).mesh_id == info.mesh_id

        d = client.curvature(info.mesh_id, degree=3, quantities=["normals", "mean", "principal"],
                             diagnostics=True)
        assert d.mean.shape == (len(positions),)
        assert d.normals.shape == (len(positions), 3)
        assert d.gaussian is None
        assert np.all(d.k1 >= d.k2)
        np.testing.assert_allclose(d.mean, exact_torus_mean(positions), rtol=0.05)
        assert d.summary.degree_requested == 3
        # Three chunks, streamed while the fit ran: the summary is the last chunk's, complete.
        assert sum(d.summary.vertices_by_degree) == len(positions)
        assert d.summary.fit_ms > 0 and not d.summary.fit_cache_hit
        assert d.diagnostics["degree_used"].min() >= 1

        again = client.curvature(info.mesh_id, degree=3, quantities=["mean"])
        assert again.summary.fit_cache_hit
        np.testing.assert_array_equal(again.mean, d.mean)

        updated = client.update_positions(info.mesh_id, 2.0 * positions, expected_revision=1)
        assert updated.revision == 2
        scaled = client.curvature(info.mesh_id, degree=3, quantities=["mean"])
        np.testing.assert_allclose(scaled.mean, d.mean / 2.0, rtol=1e-6, atol=1e-9)

        back, back_faces, back_info = client.download(info.mesh_id)
        assert back.tobytes() == (2.0 * positions).tobytes()
        np.testing.assert_array_equal(back_faces[:, :3], faces)
        assert np.all(back_faces[:, 3] == -1)
        assert back_info.revision == 2


def test_noise_modes_solvers_and_comparison_methods_by_name(server, torus_mesh):
    positions, faces = torus_mesh
    rng = np.random.default_rng(3)
    noisy = positions + 0.01 * rng.standard_normal(positions.shape)  # ~h^2 for this torus
    with geomfit.Client(server.address) as client:
        mesh_id = client.upload(noisy, faces, name="noisy torus").mesh_id
        exact = exact_torus_mean(positions)
        err = {}
        for noise in ("off", "on", "auto"):
            d = client.curvature(mesh_id, degree=2, quantities=["mean"], noise=noise)
            err[noise] = np.linalg.norm(d.mean - exact) / np.linalg.norm(exact)
        assert err["on"] < 0.5 * err["off"]
        assert err["auto"] == err["on"]  # the residual test finds the noise
        svd = client.curvature(mesh_id, degree=2, quantities=["mean"], solver="svd")
        qr = client.curvature(mesh_id, degree=2, quantities=["mean"])
        np.testing.assert_allclose(svd.mean, qr.mean, rtol=1e-6, atol=1e-8)
        for method in ("xu", "lscm"):
            assert np.all(np.isfinite(client.curvature(mesh_id, method=method, quantities=["mean"]).mean))
        with pytest.raises(ValueError, match="noise must be one of"):
            client.curvature(mesh_id, noise="sometimes")


def test_errors_carry_code_and_message(server, torus_mesh, transport):
    positions, faces = torus_mesh
    with geomfit.Client(server.address, transport=transport) as client:
        with pytest.raises(geomfit.GeomfitError) as e:
            client.curvature("m-unknown")
        assert e.value.code == grpc.StatusCode.NOT_FOUND
        assert "m-unknown" in e.value.details

        info = client.upload(positions, faces)
        with pytest.raises(geomfit.GeomfitError) as e:
            client.update_positions(info.mesh_id, positions, expected_revision=5)
        assert e.value.code == grpc.StatusCode.ABORTED
        bad = positions.copy()
        bad[4, 0] = np.inf
        with pytest.raises(geomfit.GeomfitError) as e:
            client.update_positions(info.mesh_id, bad)
        assert e.value.code == grpc.StatusCode.INVALID_ARGUMENT
        assert "vertex 4" in e.value.details
        # Both went as one message (SetPositions), not as a stream.
        calls = {m.method: m.count for m in client.statistics().methods}
        assert calls.get("SetPositions", 0) >= 2

        bad = positions.copy()
        bad[7, 2] = np.nan
        with pytest.raises(geomfit.GeomfitError) as e:
            client.upload(bad, faces)
        assert e.value.code == grpc.StatusCode.INVALID_ARGUMENT
        assert "vertex 7" in e.value.details

        bad_faces = faces.copy()
        bad_faces[11, 0] = len(positions) + 3
        with pytest.raises(geomfit.GeomfitError) as e:
            client.upload(positions, bad_faces)
        assert "face 11" in e.value.details

        with pytest.raises(geomfit.GeomfitError) as e:
            client.curvature(info.mesh_id, degree=12)
        assert e.value.code == grpc.StatusCode.INVALID_ARGUMENT
        assert "degree" in e.value.details

        assert client.get_mesh(info.mesh_id).revision == 1  # intact
        assert client.server_info().api_version == "geomfit.v1"


def test_upload_file_and_list_delete(server, tmp_path, torus_mesh):
    positions, faces = torus_mesh
    path = tmp_path / "t.obj"
    with open(path, "w") as f:
        for p in positions:
            f.write("v %.17g %.17g %.17g\n" % tuple(p))
        for t in faces + 1:
            f.write("f %d %d %d\n" % tuple(t))
    with geomfit.Client(server.address) as client:
        info = client.upload_file(str(path))
        assert info.name == "t.obj"
        back, _, _ = client.download(info.mesh_id)
        assert back.tobytes() == positions.tobytes()
        assert [m.mesh_id for m in client.list_meshes()] == [info.mesh_id]
        client.delete_mesh(info.mesh_id)
        assert client.list_meshes() == []
        stats = client.statistics()
        assert {m.method for m in stats.methods} >= {"UploadMesh", "DownloadMesh", "DeleteMesh"}


def _raw(channel, method, request_bytes):
    """A call with hand-encoded bytes: relies on nothing but the wire format."""
    return channel.unary_unary(method, request_serializer=None, response_deserializer=None)(
        request_bytes, timeout=10)


def test_health_and_reflection_without_our_stubs(server):
    from google.protobuf import descriptor_pb2
    with grpc.insecure_channel(server.address) as channel:
        assert _raw(channel, "/grpc.health.v1.Health/Check", b"") == b"\x08\x01"  # SERVING
        name = b"geomfit.v1.GeomFit"
        assert _raw(channel, "/grpc.health.v1.Health/Check", b"\x0a" + bytes([len(name)]) + name) == b"\x08\x01"

        reflect = channel.stream_stream("/grpc.reflection.v1alpha.ServerReflection/ServerReflectionInfo",
                                        request_serializer=None, response_deserializer=None)
        # ServerReflectionRequest.list_services (7) then file_containing_symbol (4).
        replies = list(reflect(iter([b"\x3a\x00", b"\x22" + bytes([len(name)]) + name]), timeout=10))
        assert name in replies[0]
        # The second reply carries FileDescriptorProto bytes: find and parse them.
        blob = replies[1]
        start = blob.index(b"geomfit/v1/geomfit.proto") - 2
        fdp = descriptor_pb2.FileDescriptorProto()
        fdp.ParseFromString(blob[start:])
        methods = {m.name for s in fdp.service for m in s.method}
        assert {"UploadMesh", "ComputeDifferentials", "GetStatistics"} <= methods


def test_durable_store_survives_kill9(data_dir, torus_mesh, transport):
    positions, faces = torus_mesh
    first = ServerProcess("--store=sqlite", "--data-dir=" + data_dir)
    try:
        with geomfit.Client(first.address, transport=transport) as client:
            info = client.upload(positions, faces, name="durable")
            client.update_positions(info.mesh_id, positions * 1.25, expected_revision=1)
    finally:
        first.kill(signal.SIGKILL)
    second = ServerProcess("--store=sqlite", "--data-dir=" + data_dir)
    try:
        with geomfit.Client(second.address) as client:
            back, back_faces, back_info = client.download(info.mesh_id)
            assert back.tobytes() == (positions * 1.25).tobytes()
            assert back_info.revision == 2
    finally:
        assert second.kill(signal.SIGTERM) == 0


def test_retry_gives_unavailable_when_nobody_listens():
    with geomfit.Client("127.0.0.1:1", max_attempts=2, backoff=0.01, timeout=2) as client:
        with pytest.raises(geomfit.GeomfitError) as e:
            client.server_info()
        assert e.value.code == grpc.StatusCode.UNAVAILABLE


def test_chapter4_project_nodes_refine_integrate(server, torus_mesh):
    positions, faces = torus_mesh
    with geomfit.Client(server.address) as client:
        mesh_id = client.upload(positions, faces, name="torus").mesh_id
        # Area and volume of the torus R = 1, r = 0.3 from the WALF surface.
        r = client.integrate(mesh_id, scalars=np.ones(len(positions)), vectors=positions, degree=4, safeguard=False)
        area, volume = 4 * np.pi ** 2 * 0.3, 2 * np.pi ** 2 * 0.09
        assert abs(r.area - area) < 1e-3 * area
        assert abs(r.volume - volume) < 1e-3 * volume
        assert abs(r.scalars[0] - r.area) < 1e-3 * area   # integral of 1
        assert abs(r.flux - 3 * r.volume) < 1e-3 * volume  # div x = 3
        flat = client.integrate(mesh_id, surface="linear")
        assert abs(flat.area - area) > 10 * abs(r.area - area)
        # Face points and xyz projections lie on the torus.
        p = client.project(mesh_id, faces=np.arange(10), natural=np.full((10, 2), 0.25))
        assert p["positions"].shape == (10, 3)
        rho = np.hypot(p["positions"][:, 0], p["positions"][:, 1])
        assert np.all(np.abs(np.hypot(rho - 1, p["positions"][:, 2]) - 0.3) < 1e-3)
        q = client.project(mesh_id, points=positions[:5] * 1.01)
        assert np.all(q["distances"] > 0) and q["faces"].dtype == np.int32
        nodes, elements = client.high_order_nodes(mesh_id, order=2)
        assert len(elements) == len(faces) and all(len(e) == 6 for e in elements)
        refined = client.refine(mesh_id, factor=2)
        assert refined.num_faces == 4 * len(faces)
        with pytest.raises(geomfit.GeomfitError) as err:
            client.project(mesh_id, faces=np.array([len(faces)]), natural=np.array([[0.1, 0.1]]))
        assert err.value.code == grpc.StatusCode.INVALID_ARGUMENT
        assert "out of range" in err.value.details
        with pytest.raises(geomfit.GeomfitError) as err:
            client.integrate(mesh_id, scalars=np.ones(len(positions) - 1))
        assert err.value.code == grpc.StatusCode.INVALID_ARGUMENT
        with pytest.raises(ValueError):
            client.integrate(mesh_id, surface="spline")


def test_messages_fit_the_servers_limit(transport):
    """A server with a small message limit: uploads and updates are cut to fit it."""
    small = ServerProcess("--store=memory", "--max-message-bytes=262144")
    try:
        positions, faces = torus(160, 80)  # 12,800 vertices: 307 KB of positions
        with geomfit.Client(small.address, transport=transport) as client:
            assert client.chunk_rows == 262144 // 4 // 24
            info = client.upload(positions, faces)
            assert info.num_vertices == len(positions)
            assert client.update_positions(info.mesh_id, 1.5 * positions, expected_revision=1).revision == 2
            back, _, _ = client.download(info.mesh_id)
            assert back.tobytes() == (1.5 * positions).tobytes()
            calls = {m.method: m.count for m in client.statistics().methods}
            assert calls.get("UpdatePositions") == 1 and "SetPositions" not in calls
    finally:
        small.kill(signal.SIGTERM)


def test_hand_serialized_set_positions_matches_protobuf():
    from geomfit.client import pb, _set_positions_request
    rng = np.random.default_rng(1)
    for n in (1, 5, 127, 128, 20000):  # one- and multi-byte varints
        p = rng.standard_normal((n, 3))
        header = pb.UpdateHeader(mesh_id="m-abc", expected_revision=7)
        ours = pb.SetPositionsRequest.FromString(_set_positions_request(header, p))
        ref = pb.SetPositionsRequest(header=header, positions=pb.PositionsChunk(
            positions=pb.DoubleArray(data=p.tobytes(), shape=[n, 3])))
        assert ours == ref
    with pytest.raises(ValueError):
        _set_positions_request(pb.UpdateHeader(mesh_id="m"), np.zeros((4, 2)))


def test_compute_request_matches_protobuf():
    client = geomfit.Client("127.0.0.1:1", transport="grpcio")
    from geomfit.client import pb
    for revision in (0, 1, 300, -1):
        for options in ({}, {"rings": 2.5, "cond_threshold": [1e3] * 6}):
            ours = pb.ComputeDifferentialsRequest.FromString(client._compute_request(
                "m-abc", revision, 3, "LOP", ("mean", "tensor"), True, options))
            ref = pb.ComputeDifferentialsRequest(
                mesh_id="m-abc", revision=revision, diagnostics=True, quantities=[2, 6],
                options=pb.FitOptions(degree=3, method=pb.FIT_METHOD_LOP, **options))
            assert ours == ref
    with pytest.raises(ValueError):
        client.curvature("m-abc", method="spline")
    with pytest.raises(ValueError):
        client.curvature("m-abc", quantities=["mean", "torsion"])
