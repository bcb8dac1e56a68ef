"""The routing key: mesh_id_of (native and pure Python) is the id the server gives an
upload, and every mesh-scoped call carries it as x-mesh-id (deploy/router)."""
import numpy as np
import pytest

import geomfit
from geomfit import client as client_module
from conftest import torus


def cube():
    positions = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)], dtype=np.float64)
    faces = np.array([[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]], np.int32)
    return positions, faces


CASES = [(torus(24, 12), "torus", {"b": "2", "a": "1"}), (cube(), "", {}), (cube(), "cube", {"k": "é"})]


@pytest.mark.parametrize("mesh,name,labels", CASES)
def test_mesh_id_of_is_the_server_id(server, mesh, name, labels):
    positions, faces = mesh
    python = client_module._mesh_id_python(positions, faces, name, labels)
    assert geomfit.mesh_id_of(positions, faces, name, labels) == python
    with geomfit.Client(server.address, transport="grpcio") as c:
        assert c.upload(positions, faces, name=name, labels=labels).mesh_id == python


def test_routing_metadata_on_every_mesh_scoped_call(server, monkeypatch):
    positions, faces = torus(16, 8)
    seen = []
    real = client_module._route
    monkeypatch.setattr(client_module, "_route", lambda mesh_id: seen.append(mesh_id) or real(mesh_id))
    with geomfit.Client(server.address, transport="grpcio") as c:
        mesh_id = c.upload(positions, faces, name="t").mesh_id
        assert seen == [mesh_id]
        c.get_mesh(mesh_id)
        c.curvature(mesh_id)
        c.update_positions(mesh_id, positions * 1.01)
        c.download(mesh_id)
        c.integrate(mesh_id)
        c.project(mesh_id, faces=[0], natural=[[0.2, 0.2]])
        c.high_order_nodes(mesh_id)
        c.refine(mesh_id)
        c.delete_mesh(mesh_id)
    assert seen == [mesh_id] * 10  # upload and the nine calls above
