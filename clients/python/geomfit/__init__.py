"""geomfit: Python client of the geomfit.v1 gRPC service (numpy in and out).

    import geomfit
    with geomfit.Client("127.0.0.1:50051") as client:
        info = client.upload(positions, faces, name="torus")
        d = client.curvature(info.mesh_id, degree=3)
        print(d.mean[:5])

The generated stubs live in _gen/ (built by CMake from proto/geomfit/v1/*.proto with
protoc and grpc_python_plugin: target geomfit_python_stubs). update_positions and
curvature go through the C++ client when the extension module _native is built
(target geomfit_native); Client(..., transport="grpcio") keeps them on grpcio.
"""
import os as _os

# The generated modules are named geomfit.v1.*: serve them from _gen/geomfit/.
_GEN = _os.path.join(_os.path.dirname(__file__), "_gen", "geomfit")
if not _os.path.isdir(_os.path.join(_GEN, "v1")):
    raise ImportError(
        "geomfit: generated stubs missing in %s; build the CMake target "
        "geomfit_python_stubs (any full build does)" % _GEN)
__path__.append(_GEN)  # noqa: F821 (package __path__)

from geomfit.client import (  # noqa: E402
    Client, Differentials, GeomfitError, MESH_ID_METADATA, QUANTITIES, mesh_id_of, read_mesh_file)

__all__ = ["Client", "Differentials", "GeomfitError", "MESH_ID_METADATA", "QUANTITIES", "mesh_id_of", "read_mesh_file"]
