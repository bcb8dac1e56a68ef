"""Jobs from Python: a refine job watched to its end, resumed from event k, cancelled."""
import grpc
import pytest

import geomfit
from geomfit.v1 import geomfit_pb2 as pb

from conftest import torus


def test_refine_job_watch_and_resume(server):
    with geomfit.Client(server.address) as client:
        positions, faces = torus(24, 12)
        mesh = client.upload(positions, faces, name="torus")
        job = client.refine_job(mesh.mesh_id, levels=2, degree=2)
        assert job.kind == "refine" and job.request.refine.levels == 2
        events = list(client.watch_job(job.job_id))
        assert [e.seq for e in events] == list(range(1, len(events) + 1))
        assert [(e.phase, e.step) for e in events if e.phase in ("refine", "stored")] == \
            [("refine", 1), ("stored", 1), ("refine", 2), ("stored", 2)]
        last = events[-1]
        assert last.final and last.state == pb.JOB_STATE_SUCCEEDED, last.message
        assert [client.get_mesh(r.mesh_id).num_faces for r in last.results] == [4 * len(faces), 16 * len(faces)]
        d = client.curvature(last.results[-1].mesh_id, degree=2)
        assert d.mean.shape == (16 * len(faces) // 2,)
        # Resuming from event k yields exactly the events >= k.
        for k in (1, 4, len(events)):
            assert list(client.watch_job(job.job_id, from_event=k)) == events[k - 1:]
        assert client.get_job(job.job_id).state == pb.JOB_STATE_SUCCEEDED
        assert [j.job_id for j in client.list_jobs()] == [job.job_id]


def test_disconnect_resume_and_cancel(server):
    with geomfit.Client(server.address) as client:
        positions, faces = torus(48, 24)
        mesh = client.upload(positions, faces, name="torus")
        before = {m.mesh_id for m in client.list_meshes()}
        job = client.refine_job(mesh.mesh_id, levels=6, degree=2)  # minutes of work
        seen = []
        for event in client.watch_job(job.job_id):  # breaking out closes the stream
            seen.append(event)
            if event.phase == "stored" and event.step == 1:
                break
        k = seen[-1].seq + 1
        resumed = client.watch_job(job.job_id, from_event=k)
        first = next(resumed)
        assert first.seq == k and (first.phase, first.step) == ("refine", 2)
        client.cancel_job(job.job_id)
        rest = list(resumed)
        assert rest[-1].final and rest[-1].state == pb.JOB_STATE_CANCELLED
        assert rest[-1].error_code == grpc.StatusCode.CANCELLED.value[0]
        assert {m.mesh_id for m in client.list_meshes()} == before  # level 1 rolled back
        done = client.get_job(job.job_id)
        assert done.state == pb.JOB_STATE_CANCELLED and not done.results


def test_job_errors(server):
    with geomfit.Client(server.address) as client:
        positions, faces = torus(24, 12)
        mesh = client.upload(positions, faces)
        with pytest.raises(geomfit.GeomfitError) as e:
            client.refine_job(mesh.mesh_id, levels=0)
        assert e.value.code == grpc.StatusCode.INVALID_ARGUMENT and "refine.levels" in e.value.details
        for call in (client.get_job, client.cancel_job, lambda j: list(client.watch_job(j))):
            with pytest.raises(geomfit.GeomfitError) as e:
                call("j-nope")
            assert e.value.code == grpc.StatusCode.NOT_FOUND
