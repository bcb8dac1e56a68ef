"""geomfit: Python client of the geomfit.v1 gRPC service (numpy in and out).

    import geomfit
    with geomfit.Client("127.0.0.1:50051") as client:
        info = client.upload_file("data/torus.obj")
        d = client.curvature(info.mesh_id, degree=4)
        print(d.mean[:5])

Install with `pip install --no-build-isolation ./clients/python`: the build generates
the stubs (_gen/) and, when the project's C++ client builds, the native transport
(_native) into the package. From a CMake build tree, put both clients/python and
build/python (the build's overlay with _gen/ and _native) on PYTHONPATH.
update_positions and curvature go through the C++ client when _native is present;
Client(..., transport="grpcio") keeps them on grpcio.
"""
import os as _os
import pkgutil as _pkgutil

# Every geomfit/ folder on sys.path is part of this package (the build tree's overlay).
__path__ = _pkgutil.extend_path(__path__, __name__)  # noqa: F821 (package __path__)

# The generated modules are named geomfit.v1.*: serve them from <package>/_gen/geomfit/.
_GEN = [g for g in (_os.path.join(p, "_gen", "geomfit") for p in __path__) if _os.path.isdir(_os.path.join(g, "v1"))]
if not _GEN:
    raise ImportError(
        "geomfit: generated stubs missing (no _gen/geomfit/v1 in %s); install the package "
        "(pip install clients/python) or build the CMake target geomfit_python_stubs and add "
        "build/python to PYTHONPATH" % list(__path__))
__path__.append(_GEN[0])

from geomfit._version import __version__  # noqa: E402
from geomfit.client import (  # noqa: E402
    Client, Differentials, GeomfitError, MESH_ID_METADATA, QUANTITIES, mesh_id_of, read_mesh_file)
from geomfit.interop import from_meshio, to_meshio  # noqa: E402

__all__ = ["Client", "Differentials", "GeomfitError", "MESH_ID_METADATA", "QUANTITIES", "__version__",
           "from_meshio", "mesh_id_of", "read_mesh_file", "to_meshio"]
