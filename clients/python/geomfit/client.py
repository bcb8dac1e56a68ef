"""The geomfit Client: numpy arrays in and out over the geomfit.v1 gRPC API."""
import dataclasses
import math
import time
from typing import Callable, Dict, Iterable, Iterator, List, Optional, Tuple

import grpc
import grpc.experimental
import numpy as np

from geomfit.progress import ProgressArg, reporting, tqdm_callback
from geomfit.readers import read_mesh_file
from geomfit.v1 import geomfit_pb2 as pb
from geomfit.v1 import geomfit_pb2_grpc as pb_grpc

try:  # the C++ client as an extension module (CMake target geomfit_native)
    from geomfit import _native
    _NATIVE_MISSING = ""
except ImportError as e:
    _native, _NATIVE_MISSING = None, str(e)

QUANTITIES = {
    "normals": pb.QUANTITY_NORMALS,
    "mean": pb.QUANTITY_MEAN_CURVATURE,
    "gaussian": pb.QUANTITY_GAUSSIAN_CURVATURE,
    "principal": pb.QUANTITY_PRINCIPAL_CURVATURES,   # k1, k2
    "directions": pb.QUANTITY_PRINCIPAL_DIRECTIONS,  # dir1, dir2
    "tensor": pb.QUANTITY_CURVATURE_TENSOR,
}
_METHODS = {"lhf": pb.FIT_METHOD_LHF, "lop": pb.FIT_METHOD_LOP, "xu": pb.FIT_METHOD_XU, "lscm": pb.FIT_METHOD_LSCM}
# FitOptions enums that callers may give by name (noise="auto", solver="svd").
_FIT_ENUMS = {"noise": {"off": pb.NOISE_MODE_OFF, "on": pb.NOISE_MODE_ON, "auto": pb.NOISE_MODE_AUTO},
              "solver": {"qr": pb.WLS_SOLVER_QR, "svd": pb.WLS_SOLVER_SVD}}
_SURFACES = {"walf": pb.RECONSTRUCTION_WALF, "cmf": pb.RECONSTRUCTION_CMF, "linear": pb.RECONSTRUCTION_LINEAR}
_ARRAYS = ("normals", "mean", "gaussian", "k1", "k2", "dir1", "dir2", "tensor")
_TRANSPORTS = ("auto", "native", "grpcio")
_STATUS_CODES = {code.value[0]: code for code in grpc.StatusCode}


class GeomfitError(Exception):
    """A failed call: `code` is the grpc.StatusCode, `details` the server's message.
    Picklable (multiprocessing, joblib, dask pass it between processes)."""

    def __init__(self, code: grpc.StatusCode, details: str):
        super().__init__("%s: %s" % (code.name, details))
        self.code = code
        self.details = details

    def __reduce__(self):
        return (type(self), (self.code, self.details))


@dataclasses.dataclass
class Differentials:
    """Per-vertex arrays (None when not requested) and the fit summary.

    Conventions: normals outward for counter-clockwise faces; H = +1/R on a sphere;
    k1 >= k2; tensor is #V x 9 (row-major 3 x 3).
    """
    summary: "pb.FitSummary"
    normals: Optional[np.ndarray] = None
    mean: Optional[np.ndarray] = None
    gaussian: Optional[np.ndarray] = None
    k1: Optional[np.ndarray] = None
    k2: Optional[np.ndarray] = None
    dir1: Optional[np.ndarray] = None
    dir2: Optional[np.ndarray] = None
    tensor: Optional[np.ndarray] = None
    diagnostics: Optional[Dict[str, np.ndarray]] = None

    def __repr__(self) -> str:
        s = self.summary
        arrays = ["%s%s" % (name, list(getattr(self, name).shape)) for name in _ARRAYS
                  if getattr(self, name) is not None]
        if self.diagnostics:
            arrays.append("diagnostics{%s}" % ",".join(sorted(self.diagnostics)))
        return "Differentials(mesh_id=%r, revision=%d, vertices=%d, %s)" % (
            s.mesh_id, s.revision, s.num_vertices, " ".join(arrays) or "no arrays")


def _encode(array: np.ndarray, dtype: str, out) -> None:
    a = np.ascontiguousarray(array, dtype=dtype)
    out.data = a.tobytes()
    out.shape[:] = list(a.shape)


def _decode(array, dtype: str) -> np.ndarray:
    return np.frombuffer(array.data, dtype=dtype).reshape(tuple(array.shape))


# ---------------------------------------------------------------- wire parsing
# Minimal protobuf wire-format reader for ComputeDifferentialsResponse: numpy views
# straight into the received bytes. Unknown fields are skipped, so additive changes
# to the .proto keep working.
_RESPONSE_ARRAYS = {4: "normals", 5: "mean", 6: "gaussian", 7: "k1", 8: "k2", 9: "dir1", 10: "dir2",
                    11: "tensor"}
_DIAGNOSTIC_ARRAYS = {1: ("points", "<i4"), 2: ("degree_used", "<i4"), 3: ("flags", "<i4"),
                      4: ("condition", "<f8")}


def _varint(buf: bytes, i: int) -> Tuple[int, int]:
    b = buf[i]
    if b < 0x80:  # one byte: field keys, small shapes
        return b, i + 1
    result, shift, i = b & 0x7F, 7, i + 1
    while True:
        b = buf[i]
        i += 1
        result |= (b & 0x7F) << shift
        if b < 0x80:
            return result, i
        shift += 7


def _fields(buf: bytes, i: int, end: int):
    """Yields (field number, value) for the fields in buf[i:end]: an int for varints,
    a (begin, end) range for length-delimited fields, None for fixed-width ones."""
    while i < end:
        key, i = _varint(buf, i)
        wire = key & 7
        if wire == 0:
            value, i = _varint(buf, i)
        elif wire == 2:
            n, i = _varint(buf, i)
            value, i = (i, i + n), i + n
        elif wire in (1, 5):
            value, i = None, i + (8 if wire == 1 else 4)
        else:
            raise GeomfitError(grpc.StatusCode.DATA_LOSS, "malformed response (wire type %d)" % wire)
        yield key >> 3, value


def _array(buf: bytes, span: Tuple[int, int], dtype: np.dtype) -> np.ndarray:
    """A DoubleArray / Int32Array message as a numpy view of `buf`."""
    data, shape = (0, 0), []
    for number, value in _fields(buf, *span):
        if number == 1:
            data = value
        elif number == 2 and isinstance(value, tuple):  # packed shape
            i = value[0]
            while i < value[1]:
                dim, i = _varint(buf, i)
                shape.append(dim)
        elif number == 2:
            shape.append(value)
    count, rest = divmod(data[1] - data[0], dtype.itemsize)
    if rest or count != math.prod(shape):
        raise GeomfitError(grpc.StatusCode.DATA_LOSS, "array of %d bytes, shape %s" % (data[1] - data[0], shape))
    return np.frombuffer(buf, dtype, count, data[0]).reshape(shape)


_F8, _I4 = np.dtype("<f8"), np.dtype("<i4")
_U64 = (1 << 64) - 1  # int64 fields are varints of their two's complement


def _varint_bytes(n: int) -> bytes:
    out = bytearray()
    while n >= 0x80:
        out.append((n & 0x7F) | 0x80)
        n >>= 7
    out.append(n)
    return bytes(out)


def _len_prefix(number: int, length: int) -> bytes:
    """Key and length of a length-delimited field."""
    return _varint_bytes((number << 3) | 2) + _varint_bytes(length)


def _positions_array(positions) -> np.ndarray:
    """Positions as a contiguous little-endian #V x 3 float64 array (ValueError otherwise)."""
    p = np.ascontiguousarray(positions, dtype="<f8")
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError("positions must be #V x 3, got shape %s" % (p.shape,))
    return p


def _faces_array(faces) -> np.ndarray:
    """Faces as contiguous little-endian int32 #F x 3|4 (ValueError for another shape, or
    values that are not integers, e.g. 2.7, or out of int32 range)."""
    a = np.asarray(faces)
    if a.dtype.kind not in "iub":
        if a.dtype.kind != "f":
            raise ValueError("faces must be integers, got dtype %s" % a.dtype)
        bad = np.argwhere(~np.isfinite(a) | (a != np.round(a)))
        if len(bad):
            raise ValueError("faces must be integers: face %d holds %r" % (bad[0][0], a[tuple(bad[0])]))
    if a.size and (a.min() < -1 or a.max() > np.iinfo(np.int32).max):
        raise ValueError("faces must be vertex indices (or -1 padding), got values in [%d, %d]" % (a.min(), a.max()))
    f = np.ascontiguousarray(a, dtype="<i4")
    if f.ndim != 2 or f.shape[1] not in (3, 4):
        raise ValueError("faces must be #F x 3 or #F x 4, got shape %s" % (f.shape,))
    return f


# ---------------------------------------------------------------- mesh ids
# The server names an upload by a hash of its content (core/mesh/content_hash.cc,
# MeshContentHash); the client computes the same id before uploading, so the
# upload carries the `x-mesh-id` routing key that every later call on the mesh carries.
_M64 = (1 << 64) - 1
MESH_ID_METADATA = "x-mesh-id"


def _mix(x: int) -> int:  # splitmix64 finalizer
    x ^= x >> 30
    x = (x * 0xBF58476D1CE4E5B9) & _M64
    x ^= x >> 27
    x = (x * 0x94D049BB133111EB) & _M64
    return x ^ (x >> 31)


class _ContentHash:
    """core/mesh/content_hash.cc in Python (bit-exact)."""

    def __init__(self):
        self.a, self.b, self.length = 0x9E3779B97F4A7C15, 0xC2B2AE3D27D4EB4F, 0

    def add(self, data: bytes) -> None:
        full = len(data) - len(data) % 8
        a, b = self.a, self.b
        for w in np.frombuffer(data, "<u8", full // 8).tolist():
            a = (_mix(a ^ w) + 0x9E3779B97F4A7C15) & _M64
            b = _mix((b + w) & _M64) ^ (a >> 7)
        tail = int.from_bytes(data[full:], "little")
        self.a = _mix(a ^ tail ^ ((len(data) - full) << 56))
        self.b = _mix((b + tail + 0x632BE59BD9B4E019) & _M64)
        self.length += len(data)

    def add_string(self, s: str) -> None:
        raw = s.encode()
        self.add(len(raw).to_bytes(8, "little"))
        self.add(raw)

    def hex(self) -> str:
        return "%016x%016x" % (_mix(self.a ^ self.length), _mix((self.b + self.length) & _M64))


def mesh_id_of(positions: np.ndarray, faces: np.ndarray, name: str = "",
               labels: Optional[Dict[str, str]] = None) -> str:
    """The mesh_id the server gives this upload (content, name and labels). Computed by
    geomfit._native when built (C++ speed), else in Python (~1 s per 100k vertices)."""
    p = _positions_array(positions)
    f = np.ascontiguousarray(faces, dtype="<i4")
    if _native is not None and hasattr(_native, "mesh_id_of") and f.ndim == 2:
        return _native.mesh_id_of(p, f, name, dict(labels or {}))
    return _mesh_id_python(p, f, name, labels)


def _mesh_id_python(p: np.ndarray, f: np.ndarray, name: str, labels: Optional[Dict[str, str]]) -> str:
    if f.ndim == 2 and f.shape[1] == 3:  # the server keeps #F x 4, triangles padded with -1
        f = np.concatenate([f, np.full((f.shape[0], 1), -1, dtype="<i4")], axis=1)
    h = _ContentHash()
    h.add(np.array([p.shape[0], f.shape[0]], dtype="<i8").tobytes())
    h.add(f.tobytes())
    h.add(p.tobytes())
    h.add_string(name)
    for k, v in sorted((labels or {}).items()):
        h.add_string(k)
        h.add_string(v)
    return "m-" + h.hex()[:20]


def _route(mesh_id: str) -> tuple:
    """Call metadata naming the mesh: the key of cache-affine routers (deploy/router)."""
    return ((MESH_ID_METADATA, mesh_id),)


def _set_positions_request(header: "pb.UpdateHeader", positions: np.ndarray) -> bytes:
    """A serialized SetPositionsRequest, the array copied once: header = 1,
    positions = 2 { vertex_offset = 1 (0, omitted), positions = 2 { shape = 2, data = 1 } }."""
    p = _positions_array(positions)
    shape = _varint_bytes(p.shape[0]) + _varint_bytes(3)
    array_head = _len_prefix(2, len(shape)) + shape + _len_prefix(1, p.nbytes)
    array_len = len(array_head) + p.nbytes
    chunk_head = _len_prefix(2, array_len)
    h = header.SerializeToString()
    return b"".join([_len_prefix(1, len(h)), h, _len_prefix(2, len(chunk_head) + array_len), chunk_head,
                     array_head, memoryview(p).cast("B")])


def _parse_chunk(raw: bytes) -> dict:
    out = {"summary": None, "vertex_offset": 0, "num_vertices": 0, "arrays": {}, "diagnostics": {},
           "progress": None}
    for number, value in _fields(raw, 0, len(raw)):
        if number == 13:  # a progress message (phase, done, total), nothing else set
            p = {1: (0, 0), 2: 0, 3: 0}
            p.update(_fields(raw, *value))
            out["progress"] = (raw[p[1][0]:p[1][1]].decode(), p[2], p[3])
        elif number == 1:
            out["summary"] = raw[value[0]:value[1]]
        elif number == 2:
            out["vertex_offset"] = value
        elif number == 3:
            out["num_vertices"] = value
        elif number in _RESPONSE_ARRAYS:
            out["arrays"][_RESPONSE_ARRAYS[number]] = _array(raw, value, _F8)
        elif number == 12:
            for n, v in _fields(raw, *value):
                if n in _DIAGNOSTIC_ARRAYS:
                    name, dtype = _DIAGNOSTIC_ARRAYS[n]
                    out["diagnostics"][name] = _array(raw, v, np.dtype(dtype))
    return out


class _BearerToken(grpc.UnaryUnaryClientInterceptor, grpc.UnaryStreamClientInterceptor,
                   grpc.StreamUnaryClientInterceptor, grpc.StreamStreamClientInterceptor):
    """Adds `authorization: Bearer TOKEN` to every call of a channel."""

    def __init__(self, token: str):
        self._metadata = ("authorization", "Bearer " + token)

    def _details(self, d):
        return d._replace(metadata=list(d.metadata or []) + [self._metadata])

    def intercept_unary_unary(self, continuation, d, request):
        return continuation(self._details(d), request)

    def intercept_unary_stream(self, continuation, d, request):
        return continuation(self._details(d), request)

    def intercept_stream_unary(self, continuation, d, requests):
        return continuation(self._details(d), requests)

    def intercept_stream_stream(self, continuation, d, requests):
        return continuation(self._details(d), requests)


class Client:
    """Client of a geomfit server. Every call has a deadline (`timeout` seconds);
    UNAVAILABLE is retried `max_attempts` times with exponential backoff. Errors
    raise GeomfitError. Use as a context manager to close the channel.

    `transport` carries the per-time-step calls, update_positions (when it fits in one
    message) and curvature: "native" sends them through the C++ client (the extension
    module geomfit._native, built by CMake target geomfit_native), "grpcio" through
    grpcio like every other call, "auto" (the default) natively when the module is
    built. Both give the same results; `client.transport` says which one is in use.

    TLS: `tls_ca` (PEM file of the CA that signed the server's certificate), and for
    mTLS `tls_cert` + `tls_key` (PEM files of the client certificate); `tls=True` alone
    uses the system's roots. Both transports use the same credentials (the native one
    gets the file paths). `token`: the bearer token of a server run with --auth-tokens
    (sent on every call by both transports).
    """

    def __init__(self, target: str = "127.0.0.1:50051", timeout: float = 120.0, max_attempts: int = 4,
                 backoff: float = 0.1, chunk_rows: int = 0, max_message_bytes: int = 64 << 20,
                 transport: str = "auto", tls: bool = False, tls_ca: Optional[str] = None,
                 tls_cert: Optional[str] = None, tls_key: Optional[str] = None, token: Optional[str] = None):
        if transport not in _TRANSPORTS:
            raise ValueError("transport must be one of %s, got %r" % (_TRANSPORTS, transport))
        if transport == "native" and _native is None:
            raise ImportError("geomfit: transport='native' needs the extension module geomfit._native (%s); "
                              "build the CMake target geomfit_native (any full build does, with pybind11-dev "
                              "and python3-dev from scripts/install-deps.sh)" % _NATIVE_MISSING)
        self.transport = "native" if _native is not None and transport != "grpcio" else "grpcio"
        self.target = target
        self.timeout = timeout
        self.max_attempts = max(1, max_attempts)
        self.backoff = backoff
        # Rows per upload/update message; 0: as many as fill a quarter of the smaller of
        # this client's and the server's message limits (grpcio pays per message sent).
        self._chunk_rows = chunk_rows if chunk_rows > 0 else None
        self._max_message_bytes = max_message_bytes
        channel_options = [
            ("grpc.max_receive_message_length", max_message_bytes),
            ("grpc.max_send_message_length", max_message_bytes),
            # Server-streaming calls run on the calling thread: no hand-off per call.
            (grpc.experimental.ChannelOptions.SingleThreadedUnaryStream, 1),
        ]
        if bool(tls_cert) != bool(tls_key):
            raise ValueError("tls_cert and tls_key go together")
        self._tls_files = (tls_ca or "", tls_cert or "", tls_key or "")
        self.tls = bool(tls or any(self._tls_files))
        if self.tls:
            def read(path):
                with open(path, "rb") as f:
                    return f.read()
            credentials = grpc.ssl_channel_credentials(
                root_certificates=read(tls_ca) if tls_ca else None,
                private_key=read(tls_key) if tls_key else None,
                certificate_chain=read(tls_cert) if tls_cert else None)
            self._channel = grpc.secure_channel(target, credentials, options=channel_options)
        else:
            self._channel = grpc.insecure_channel(target, options=channel_options)
        self._raw_channel = self._channel
        if token:
            self._channel = grpc.intercept_channel(self._channel, _BearerToken(token))
        self._stub = pb_grpc.GeomFitStub(self._channel)
        self._stream_updates = False
        self._unary_only = False  # the server lacks HighOrderNodesStream & co. (see _long)
        # ComputeDifferentials requests come serialized (_compute_request); responses are
        # read as raw bytes and their arrays viewed in place (_parse_chunk): the
        # generated parser would copy every array twice.
        self._compute = self._channel.unary_stream(
            "/geomfit.v1.GeomFit/ComputeDifferentials", request_serializer=None, response_deserializer=None)
        self._request_tails: Dict[tuple, bytes] = {}  # see _compute_request
        # SetPositions requests are serialized by _set_positions_request (one copy of the
        # array instead of three).
        self._set_positions = self._channel.unary_unary(
            "/geomfit.v1.GeomFit/SetPositions", request_serializer=None, response_deserializer=pb.MeshInfo.FromString)
        self._native = None
        if self.transport == "native":
            # What update_positions sends as one message the C++ client sends as one
            # message too: its chunk_rows is at least this client's.
            self._native = _native.Client(
                target, timeout, self.max_attempts, backoff, max_message_bytes,
                chunk_rows=chunk_rows if chunk_rows > 0 else max(1, max_message_bytes // 4 // 24),
                tls=self.tls, tls_ca=self._tls_files[0], tls_cert=self._tls_files[1], tls_key=self._tls_files[2],
                token=token or "")

    def close(self) -> None:
        """Closes the channel (and the native client's). The client is unusable after."""
        self._raw_channel.close()
        self._native = None  # the C++ client's channel goes with it

    def __enter__(self) -> "Client":
        """The client itself; leaving the block closes it."""
        return self

    def __exit__(self, *exc) -> None:
        """Closes the client."""
        self.close()

    # ------------------------------------------------------------------ plumbing
    @property
    def chunk_rows(self) -> int:
        """Rows per upload/update message (asks the server for its limit once)."""
        if self._chunk_rows is None:
            try:
                server = self.server_info().max_message_bytes
            except GeomfitError:
                return 16384  # the server's limit is unknown (the call itself will say why)
            limit = min(self._max_message_bytes, server or self._max_message_bytes)
            self._chunk_rows = max(1, limit // 4 // 24)
        return self._chunk_rows

    def _call(self, fn):
        delay = self.backoff
        for attempt in range(1, self.max_attempts + 1):
            try:
                return fn()
            except grpc.RpcError as e:  # grpc.Call carries code() and details()
                code = e.code()
                if code == grpc.StatusCode.UNAVAILABLE and attempt < self.max_attempts:
                    time.sleep(delay)
                    delay = min(2.0, delay * 2)
                    continue
                raise GeomfitError(code, e.details() or "") from None
        raise AssertionError("unreachable")

    @staticmethod
    def _call_native(fn):
        """A call through geomfit._native (which retries UNAVAILABLE itself)."""
        try:
            return fn()
        except _native.RpcError as e:
            code, details = e.args
            raise GeomfitError(_STATUS_CODES.get(code, grpc.StatusCode.UNKNOWN), details) from None

    def _position_chunks(self, positions: np.ndarray) -> Iterable["pb.PositionsChunk"]:
        p = _positions_array(positions)
        for b in range(0, p.shape[0], self.chunk_rows):
            c = pb.PositionsChunk(vertex_offset=b)
            _encode(p[b:b + self.chunk_rows], "<f8", c.positions)
            yield c

    # ------------------------------------------------------------------ meshes
    def upload(self, positions: np.ndarray, faces: np.ndarray, name: str = "",
               labels: Optional[Dict[str, str]] = None) -> "pb.MeshInfo":
        """Uploads a mesh (positions #V x 3; faces #F x 3, or #F x 4 with -1 padding
        triangles, integers: ValueError for non-integral values such as 2.7); returns
        MeshInfo. Identical content returns the same mesh_id."""
        f = _faces_array(faces)
        header = pb.MeshHeader(num_vertices=len(positions), num_faces=f.shape[0], name=name,
                               labels=labels or {})
        requests = [pb.UploadMeshRequest(header=header)]
        requests += [pb.UploadMeshRequest(positions=c) for c in self._position_chunks(positions)]
        for b in range(0, f.shape[0], self.chunk_rows):
            c = pb.FacesChunk(face_offset=b)
            _encode(f[b:b + self.chunk_rows], "<i4", c.faces)
            requests.append(pb.UploadMeshRequest(faces=c))
        route = _route(mesh_id_of(positions, f, name, labels))
        return self._call(lambda: self._stub.UploadMesh(iter(requests), timeout=self.timeout, metadata=route))

    def upload_file(self, path: str, name: Optional[str] = None,
                    labels: Optional[Dict[str, str]] = None) -> "pb.MeshInfo":
        """Reads a mesh file with read_mesh_file (OBJ, OFF, PLY ascii/binary, STL
        ascii/binary; geomfit's C++ readers when the native module is built) and uploads
        it, named after the file unless `name` is given."""
        import os
        positions, faces = read_mesh_file(path)
        return self.upload(positions, faces, name=os.path.basename(path) if name is None else name, labels=labels)

    def update_positions(self, mesh_id: str, positions: np.ndarray,
                         expected_revision: Optional[int] = None) -> "pb.MeshInfo":
        """New positions for the same faces; ABORTED if expected_revision is stale. The
        array is read in place while the call runs: other threads must not modify it."""
        one_message = 0 < len(positions) <= self.chunk_rows and not self._stream_updates
        if one_message and self._native is not None:
            p = _positions_array(positions)  # read in place by the C++ client
            return self._call_native(lambda: pb.MeshInfo.FromString(
                self._native.set_positions(mesh_id, p, expected_revision)))
        header = pb.UpdateHeader(mesh_id=mesh_id)
        if expected_revision is not None:
            header.expected_revision = expected_revision
        if one_message:
            # One message (SetPositions): grpcio's client streams start a thread per call.
            request = _set_positions_request(header, positions)
            try:
                return self._call(lambda: self._set_positions(request, timeout=self.timeout,
                                                                      metadata=_route(mesh_id)))
            except GeomfitError as e:
                if e.code != grpc.StatusCode.UNIMPLEMENTED:
                    raise
                self._stream_updates = True  # a server without SetPositions
        requests = [pb.UpdatePositionsRequest(header=header)]
        requests += [pb.UpdatePositionsRequest(positions=c) for c in self._position_chunks(positions)]
        return self._call(lambda: self._stub.UpdatePositions(iter(requests), timeout=self.timeout,
                                                                     metadata=_route(mesh_id)))

    def get_mesh(self, mesh_id: str) -> "pb.MeshInfo":
        """The MeshInfo of a stored mesh (NOT_FOUND if there is none)."""
        return self._call(lambda: self._stub.GetMesh(pb.GetMeshRequest(mesh_id=mesh_id), timeout=self.timeout,
                                                             metadata=_route(mesh_id)))

    def download(self, mesh_id: str) -> Tuple[np.ndarray, np.ndarray, "pb.MeshInfo"]:
        """(positions #V x 3, faces #F x 4 with -1 padding, MeshInfo)."""
        def run():
            info, positions, faces = None, None, None
            for r in self._stub.DownloadMesh(pb.DownloadMeshRequest(mesh_id=mesh_id), timeout=self.timeout,
                                            metadata=_route(mesh_id)):
                which = r.WhichOneof("chunk")
                if which == "info":
                    info = r.info
                    positions = np.empty((info.num_vertices, 3), dtype=np.float64)
                    faces = np.empty((info.num_faces, 4), dtype=np.int32)
                elif which == "positions":
                    a = _decode(r.positions.positions, "<f8")
                    positions[r.positions.vertex_offset:r.positions.vertex_offset + len(a)] = a
                elif which == "faces":
                    a = _decode(r.faces.faces, "<i4")
                    faces[r.faces.face_offset:r.faces.face_offset + len(a)] = a
            return positions, faces, info
        return self._call(run)

    def list_meshes(self) -> List["pb.MeshInfo"]:
        """Every stored mesh's MeshInfo."""
        return self._all_pages(self._stub.ListMeshes, pb.ListMeshesRequest, "meshes")

    def _all_pages(self, rpc, request_type, field: str) -> list:
        """Every item of a paged List* call (pages of 1000)."""
        out, token = [], ""
        while True:
            r = self._call(lambda: rpc(request_type(page_size=1000, page_token=token), timeout=self.timeout))
            out.extend(getattr(r, field))
            if not r.next_page_token:
                return out
            token = r.next_page_token

    def delete_mesh(self, mesh_id: str) -> None:
        """Deletes a mesh and its cached results (NOT_FOUND if there is none)."""
        self._call(lambda: self._stub.DeleteMesh(pb.DeleteMeshRequest(mesh_id=mesh_id), timeout=self.timeout,
                                                         metadata=_route(mesh_id)))

    # ------------------------------------------------------------------ geometry
    def curvature(self, mesh_id: str, degree: int = 0, method: str = "lhf",
                  quantities: Iterable[str] = ("normals", "mean", "gaussian", "principal"),
                  revision: int = 0, diagnostics: bool = False, progress: ProgressArg = None,
                  **options) -> Differentials:
        """Differential quantities per vertex. `options` are further FitOptions fields
        (rings, adaptive, safeguard_angle_deg, interpolate, two_pass, noise="off"|"on"|"auto",
        smoothing_passes, solver="qr"|"svd", normal_degree, ...); unset ones take the server
        defaults (degree 0 = 2). normal_degree: normal refinement, a first fit of that degree
        (> degree) fixes the tangent plane, so degree=2, normal_degree=3 gives O(h^3) normals
        with the degree-2 curvatures (0 = off, the default). hermite_hessian=True (degree 2):
        curvatures from the stencil's heights and refined normals jointly (the quartic term
        cancels; implies normal_degree=3). slope_refinement=2 (degree 2; 1-3 passes): the same kind
        of normals and curvatures from the neighbours' degree-2 normals on the same stencils
        (no degree-3 pre-fit; ~4.8x a plain fit in process): the best clean-mesh accuracy at degree 2 (one
        pass, ~4.4x, reaches 0.48x CGAL's max-norm errors on marching-cubes meshes).
        quadratic_hermite=True (degree 2; off by default): the fit's own operator applied twice
        more with the neighbours' fitted normals (the cubic term cancels; <= 0.42x CGAL's on clean
        meshes at ~2.5x a plain fit; ignored with slope_refinement). cubic_hermite=False
        (degree 3): the plain fit's normals and curvatures instead of the slope refinement and
        Hermite refit (on by default). jet_hermite=True / False (degrees 4-5): the Hessian and
        gradient refitted with the neighbours' fitted slopes (H, K ~0.5x CGAL's or better) or the
        plain fit's (unset: on at degree 5, off at degree 4). plane_hermite=False (degree 1): the
        plain plane fit's normals (by default their O(h) bias, a known map of the Hessian, is
        removed with the neighbours' normals: order 2, <= ~0.3x CGAL's). method: "lhf", "lop", or the
        comparison methods "xu", "lscm".
        `progress`: callable(phase, done, total) or True (geomfit.progress), called with the
        server's phases of the fit ("noise test", "smooth 1/2", "smooth 2/2", "frames",
        "normals", "fit": see the user guide), and ("compute", rows received, #V) while no fit
        pass is under way (a cached result). With `progress` the call goes over grpcio, also
        with the native transport (same results, bit for bit)."""
        request = self._compute_request(mesh_id, revision, degree, method, tuple(quantities), diagnostics, options)
        if self._native is not None and not progress:
            summary, arrays, diag = self._call_native(lambda: self._native.compute(request))
            return Differentials(summary=pb.FitSummary.FromString(summary), diagnostics=diag, **arrays)
        with reporting(progress) as report:
            if report is not None:
                request += b"\x38\x01"  # progress = 7: true
            return self._call(lambda: self._compute_stream(mesh_id, request, report))

    def _compute_stream(self, mesh_id: str, request: bytes, report) -> Differentials:
        """ComputeDifferentials over grpcio, the arrays viewed in place."""
        out = None
        fitting = False  # a server phase is under way (its last message had done < total)
        for raw in self._compute(request, timeout=self.timeout, metadata=_route(mesh_id)):
            chunk = _parse_chunk(raw)
            if chunk["progress"] is not None:
                phase, done, total_units = chunk["progress"]
                fitting = done < total_units
                report(phase, done, total_units)
                continue
            if out is None:
                out = Differentials(summary=pb.FitSummary.FromString(chunk["summary"]))
                total = out.summary.num_vertices
            elif chunk["summary"] is not None:  # the last chunk completes the summary
                out.summary = pb.FitSummary.FromString(chunk["summary"])
            lo = chunk.get("vertex_offset", 0)
            for name, a in chunk["arrays"].items():
                if getattr(out, name) is None:
                    setattr(out, name, np.empty((total,) + a.shape[1:], dtype=np.float64))
                getattr(out, name)[lo:lo + len(a)] = a
            if chunk["diagnostics"]:
                if out.diagnostics is None:
                    out.diagnostics = {k: np.empty(total, dtype=a.dtype)
                                       for k, a in chunk["diagnostics"].items()}
                for k, a in chunk["diagnostics"].items():
                    out.diagnostics[k][lo:lo + len(a)] = a
            if report is not None and not fitting:
                report("compute", lo + chunk["num_vertices"], total)
        return out

    def _compute_request(self, mesh_id: str, revision: int, degree: int, method: str, quantities: Tuple[str, ...],
                         diagnostics: bool, options: dict) -> bytes:
        """A serialized ComputeDifferentialsRequest. The fields after mesh_id and revision
        are validated and serialized once per distinct set: building protobuf messages
        costs more per call than the native transport's whole overhead."""
        key = (degree, method, quantities, diagnostics, repr(sorted(options.items())) if options else "")
        tail = self._request_tails.get(key)
        if tail is None:
            if method.lower() not in _METHODS:
                raise ValueError("method must be one of %s, got %r" % (sorted(_METHODS), method))
            options = dict(options)
            for name, values in _FIT_ENUMS.items():
                if isinstance(options.get(name), str):
                    if options[name].lower() not in values:
                        raise ValueError("%s must be one of %s, got %r" % (name, sorted(values), options[name]))
                    options[name] = values[options[name].lower()]
            unknown = [q for q in quantities if q not in QUANTITIES]
            if unknown:
                raise ValueError("unknown quantities %s; choose from %s" % (unknown, sorted(QUANTITIES)))
            tail = pb.ComputeDifferentialsRequest(
                diagnostics=diagnostics, options=pb.FitOptions(degree=degree, method=_METHODS[method.lower()], **options),
                quantities=[QUANTITIES[q] for q in quantities]).SerializeToString()
            if len(self._request_tails) >= 64:
                self._request_tails.clear()
            self._request_tails[key] = tail
        m = mesh_id.encode()  # mesh_id = 1, revision = 2 (a varint, omitted when 0)
        return b"".join([_len_prefix(1, len(m)), m, b"\x10" + _varint_bytes(revision & _U64) if revision else b"", tail])

    # ------------------------------------------------------------------ chapter 4
    @staticmethod
    def _surface(surface: str, degree: int, safeguard: Optional[bool], feature_angle: float) -> "pb.ReconstructionOptions":
        """Reconstruction options; degree 0 and safeguard None take the server's defaults
        (the core ReconstructionOptions: degree 3, oscillation safeguard on)."""
        if surface.lower() not in _SURFACES:
            raise ValueError("surface must be one of %s, got %r" % (sorted(_SURFACES), surface))
        fit = pb.FitOptions(degree=degree)
        if safeguard is not None:
            fit.oscillation_safeguard = safeguard
        return pb.ReconstructionOptions(fit=fit, method=_SURFACES[surface.lower()], feature_angle_deg=feature_angle)

    def project(self, mesh_id: str, points: Optional[np.ndarray] = None, faces: Optional[np.ndarray] = None,
                natural: Optional[np.ndarray] = None, surface: str = "walf", degree: int = 0,
                safeguard: Optional[bool] = None, feature_angle: float = 0.0, progress: ProgressArg = None) -> dict:
        """Points on the high-order surface: projections of xyz `points` (P x 3), or face
        points given by `faces` (P) and natural coordinates `natural` (P x 2). Returns a
        dict of arrays: positions, normals (P x 3), faces (P), natural (P x 2), distances (P).
        `progress`: callable(phase, done, total) or True (geomfit.progress): the server's
        progress messages (phases "fit", then "project" or "evaluate points")."""
        request = pb.ProjectPointsRequest(mesh_id=mesh_id, options=self._surface(surface, degree, safeguard, feature_angle))
        if points is not None:
            _encode(np.asarray(points).reshape(-1, 3), "<f8", request.points)
        if faces is not None or natural is not None:
            _encode(np.asarray(faces).reshape(-1), "<i4", request.faces)
            _encode(np.asarray(natural).reshape(-1, 2), "<f8", request.natural)

        def run(report):
            parts = []
            for c in self._stub.ProjectPoints(request, timeout=self.timeout, metadata=_route(mesh_id)):
                if c.HasField("progress"):
                    report(c.progress.phase, c.progress.done, c.progress.total)
                else:
                    parts.append(c)
            out = {}
            for key, dtype in (("positions", "<f8"), ("normals", "<f8"), ("faces", "<i4"), ("natural", "<f8"),
                               ("distances", "<f8")):
                out[key] = np.concatenate([_decode(getattr(c, key), dtype) for c in parts])
            return out
        with reporting(progress) as report:
            request.progress = report is not None
            return self._call(lambda: run(report))

    def _long(self, name: str, request, mesh_id: str, progress: ProgressArg):
        """The unary call `name`, or with `progress` its streaming variant name + "Stream":
        the server's progress messages reported, then its last message (the unary call
        on a server without the variant)."""
        with reporting(progress) as report:
            if report is not None and not self._unary_only:
                def run():
                    last = None
                    for m in getattr(self._stub, name + "Stream")(request, timeout=self.timeout,
                                                                  metadata=_route(mesh_id)):
                        if m.HasField("progress"):
                            report(m.progress.phase, m.progress.done, m.progress.total)
                        else:
                            last = m
                    return last
                try:
                    return self._call(run)
                except GeomfitError as e:
                    if e.code != grpc.StatusCode.UNIMPLEMENTED:
                        raise
                    self._unary_only = True
        return self._call(lambda: getattr(self._stub, name)(request, timeout=self.timeout, metadata=_route(mesh_id)))

    def high_order_nodes(self, mesh_id: str, order: int = 2, surface: str = "walf", degree: int = 0,
                         safeguard: Optional[bool] = None, feature_angle: float = 0.0,
                         progress: ProgressArg = None) -> Tuple[np.ndarray, List[np.ndarray]]:
        """Quadratic or cubic element nodes on the surface: (nodes N x 3, a list with each
        face's node ids in VTK / gmsh Lagrange order). `progress`: callable(phase, done,
        total) or True (geomfit.progress): phases "fit" and "evaluate points"
        (HighOrderNodesStream)."""
        r = self._long("HighOrderNodes", pb.HighOrderNodesRequest(
            mesh_id=mesh_id, order=order, options=self._surface(surface, degree, safeguard, feature_angle)),
            mesh_id, progress)
        offsets, elements = _decode(r.offsets, "<i4"), _decode(r.elements, "<i4")
        return _decode(r.nodes, "<f8"), [elements[a:b] for a, b in zip(offsets[:-1], offsets[1:])]

    def refine(self, mesh_id: str, factor: int = 2, surface: str = "walf", degree: int = 0,
               safeguard: Optional[bool] = None, feature_angle: float = 0.0, name: str = "",
               progress: ProgressArg = None) -> "pb.MeshInfo":
        """Uniform refinement onto the surface, stored by the server as a new mesh.
        `progress`: callable(phase, done, total) or True (geomfit.progress): phases "fit"
        and "evaluate points" (RefineMeshStream)."""
        r = self._long("RefineMesh", pb.RefineMeshRequest(
            mesh_id=mesh_id, factor=factor, name=name, options=self._surface(surface, degree, safeguard, feature_angle)),
            mesh_id, progress)
        return r.mesh if isinstance(r, pb.RefineMeshResponse) else r

    def integrate(self, mesh_id: str, scalars: Optional[np.ndarray] = None, vectors: Optional[np.ndarray] = None,
                  surface: str = "walf", degree: int = 0, quadrature_degree: int = 0,
                  safeguard: Optional[bool] = None, progress: ProgressArg = None) -> "pb.IntegrateResponse":
        """Area, enclosed volume, integrals of nodal scalar fields (V or V x s) and the flux
        of a nodal vector field (V x 3) over the reconstructed surface. `progress`:
        callable(phase, done, total) or True (geomfit.progress): phases "fit",
        "integrate: fields" (with fields) and "integrate" (IntegrateStream)."""
        request = pb.IntegrateRequest(mesh_id=mesh_id, quadrature_degree=quadrature_degree,
                                      options=self._surface(surface, degree, safeguard, 0.0))
        if scalars is not None:
            _encode(np.asarray(scalars), "<f8", request.scalars)
        if vectors is not None:
            _encode(np.asarray(vectors).reshape(-1, 3), "<f8", request.vectors)
        return self._long("Integrate", request, mesh_id, progress)

    # ------------------------------------------------------------------ server
    def server_info(self) -> "pb.ServerInfo":
        """The server's version, limits and options (GetServerInfo)."""
        return self._call(lambda: self._stub.GetServerInfo(pb.GetServerInfoRequest(), timeout=self.timeout))

    def statistics(self) -> "pb.Statistics":
        """The server's counters: requests, cache use, timings (GetStatistics)."""
        return self._call(lambda: self._stub.GetStatistics(pb.GetStatisticsRequest(), timeout=self.timeout))

    # ------------------------------------------------------------------ jobs
    def start_job(self, request: Optional["pb.StartJobRequest"] = None, **spec) -> "pb.Job":
        """Starts a job and returns it at once (state PENDING or later): pass a
        StartJobRequest, or its spec as a keyword, e.g. refine=pb.RefineJob(...)."""
        if request is None:
            request = pb.StartJobRequest(**spec)
        elif spec:
            raise ValueError("give a StartJobRequest or a spec keyword, not both")
        return self._call(lambda: self._stub.StartJob(request, timeout=self.timeout))

    def watch_job(self, job_id: str, from_event: int = 0, timeout: Optional[float] = None,
                  progress: Optional[Callable[["pb.JobEvent"], None]] = None) -> Iterator["pb.JobEvent"]:
        """Iterates over the job's events with seq >= from_event as they come; ends after
        the final one (event.final). A dropped connection (UNAVAILABLE) is resumed from
        the last event seen, up to max_attempts times in a row; to resume yourself later,
        pass from_event = last seq + 1. Closing the iterator (break) cancels the call.
        `timeout`: for the whole watch (None: none; jobs may run for hours).
        `progress`: called with each event before it is yielded (event.phase, event.step,
        event.done of event.total); geomfit.progress.tqdm_callback() (or True) draws a tqdm bar."""
        if progress is True:
            progress = tqdm_callback()
        next_seq, failures, delay = from_event, 0, self.backoff
        while True:
            call = self._stub.WatchJob(pb.WatchJobRequest(job_id=job_id, from_event=next_seq), timeout=timeout)
            progressed = False
            try:
                for event in call:
                    progressed = True
                    next_seq = event.seq + 1
                    if progress is not None:
                        progress(event)
                    yield event
                return
            except grpc.RpcError as e:
                code = e.code()
                failures = 1 if progressed else failures + 1
                if code != grpc.StatusCode.UNAVAILABLE or failures >= self.max_attempts:
                    raise GeomfitError(code, e.details() or "") from None
            finally:
                call.cancel()
            time.sleep(delay)
            delay = min(2.0, delay * 2)

    def wait_job(self, job_id: str, progress: Optional[Callable[["pb.JobEvent"], None]] = None,
                 timeout: Optional[float] = None) -> "pb.JobEvent":
        """Watches a job to its end and returns the final event (results, error_code);
        `progress` as in watch_job."""
        event = None
        for event in self.watch_job(job_id, timeout=timeout, progress=progress):
            pass
        return event

    def cancel_job(self, job_id: str) -> "pb.Job":
        """Cancels a job (a running one stops as soon as it notices and stores nothing);
        a finished job is returned unchanged."""
        return self._call(lambda: self._stub.CancelJob(pb.CancelJobRequest(job_id=job_id), timeout=self.timeout))

    def get_job(self, job_id: str) -> "pb.Job":
        """A job's record: state, results, error and its latest event."""
        return self._call(lambda: self._stub.GetJob(pb.GetJobRequest(job_id=job_id), timeout=self.timeout))

    def list_jobs(self) -> List["pb.Job"]:
        """Every job, in creation order."""
        return self._all_pages(self._stub.ListJobs, pb.ListJobsRequest, "jobs")

    def refine_job(self, mesh_id: str, levels: int, factor: int = 2, surface: str = "walf", degree: int = 3,
                   safeguard: bool = True, feature_angle: float = 0.0, name: str = "",
                   revision: int = 0) -> "pb.Job":
        """Starts a `refine` job: `levels` uniform refinements (factor 2 or 3) on the
        high-order surface, each level stored as a new mesh; the final event's results
        list them, coarsest first. Watch it with watch_job(job.job_id)."""
        return self.start_job(refine=pb.RefineJob(
            mesh_id=mesh_id, revision=revision, levels=levels, factor=factor, name=name,
            options=self._surface(surface, degree, safeguard, feature_angle)))

    # ------------------------------------------------------------------ flows and operators
    def start_flow(self, mesh_id: str, dt: float, steps: int = 0, end_time: float = 0.0, kind: str = "mcf",
                   scheme: str = "semi_implicit", degree: int = 0, solver: str = "", snapshot_every: int = 0,
                   max_area_change: float = 0.0, max_volume_change: float = 0.0, send_positions: bool = False,
                   revision: int = 0, time_tolerance: Optional[float] = None) -> "pb.Job":
        """Starts a flow job (kind "mcf" or "surface_diffusion"; scheme "explicit",
        "semi_implicit" or "bdf2"); degree 0 keeps the flow's default (4). Every
        `snapshot_every` steps and at the end the positions become a new revision of the
        mesh. `time_tolerance`: iterative solves stop at this factor times the step's
        truncation error (None: the server's default 1e-3; 0: every solve to 1e-12).
        Returns the job at once; watch_job(job.job_id) streams its events."""
        spec = pb.FlowJob(mesh_id=mesh_id, revision=revision, kind=kind, scheme=scheme, dt=dt, steps=steps,
                          end_time=end_time, solver=solver, snapshot_every=snapshot_every,
                          max_area_change=max_area_change, max_volume_change=max_volume_change,
                          send_positions=send_positions)
        if degree:
            spec.fit.degree = degree
        if time_tolerance is not None:
            spec.time_tolerance = time_tolerance
        return self._call(lambda: self._stub.StartFlow(spec, timeout=self.timeout))

    def flow(self, mesh_id: str, dt: float, steps: int = 0, progress: ProgressArg = None,
             **options) -> Iterator["pb.JobEvent"]:
        """Runs a flow (start_flow's options) and iterates over its job events as they
        come: phase "step" (event.step, event.time, values area, volume, max_speed,
        fit_ms, assemble_ms, solve_ms, step_ms; counts solver_iterations) and "snapshot"
        (results: the stored revision; arrays "positions" with send_positions=True), then
        the final event. A failed or cancelled job raises GeomfitError after its final
        event; closing the iterator early (break) cancels the job. `progress`:
        callable(phase, done, total) or True (geomfit.progress): every event's phase and
        done of total (phase "step": steps done of steps)."""
        yield from self._job_events(self.start_flow(mesh_id, dt, steps, **options), progress)

    def _job_events(self, job: "pb.Job", progress: ProgressArg = None) -> Iterator["pb.JobEvent"]:
        """The events of `job` as they come, its final one included (each reported to
        `progress` first); a failed or cancelled job raises GeomfitError after its final
        event; closing the iterator early (break) cancels the job."""
        with reporting(progress) as report:
            yield from self._job_events_reported(job, report)

    def _job_events_reported(self, job: "pb.Job", report) -> Iterator["pb.JobEvent"]:
        finished = False
        try:
            for event in self.watch_job(job.job_id):
                if report is not None and event.phase:
                    report(event.phase, event.done, event.total)
                if event.final:
                    finished = True
                    yield event
                    if event.state != pb.JOB_STATE_SUCCEEDED:
                        raise GeomfitError(_STATUS_CODES.get(event.error_code, grpc.StatusCode.UNKNOWN),
                                           event.message)
                    return
                yield event
        finally:
            if not finished:
                try:
                    self.cancel_job(job.job_id)
                except GeomfitError:
                    pass

    _OPERATORS = {"gradient": 1, "divergence": 2, "laplace_beltrami": 3, "hessian": 4, "weingarten": 5}

    @classmethod
    def _operator_kind(cls, name: str) -> int:
        if name not in cls._OPERATORS:
            raise ValueError(f"operator {name!r}: expected one of {', '.join(cls._OPERATORS)}")
        return cls._OPERATORS[name]

    def operator(self, mesh_id: str, name: str = "laplace_beltrami", degree: int = 4, revision: int = 0):
        """The GFD operator `name` (gradient 3n x n, divergence n x 3n, laplace_beltrami
        n x n, hessian 9n x n, weingarten 3n x 3n) of the mesh's LHF fits: a
        scipy.sparse.csr_matrix when scipy is importable, else a tuple (row_offsets,
        columns, values, shape) of numpy arrays."""
        request = pb.GetOperatorRequest(mesh_id=mesh_id, revision=revision, operator=self._operator_kind(name),
                                        options=pb.FitOptions(degree=degree))
        out = self._call(lambda: self._stub.GetOperator(request, timeout=self.timeout, metadata=_route(mesh_id)))
        parts = (_decode(out.row_offsets, "<i4"), _decode(out.columns, "<i4"), _decode(out.values, "<f8"),
                 tuple(out.shape))
        try:
            import scipy.sparse
        except ImportError:
            return parts
        return scipy.sparse.csr_matrix((parts[2], parts[1], parts[0]), shape=parts[3])

    def apply_operator(self, mesh_id: str, field: np.ndarray, name: str = "laplace_beltrami", degree: int = 4,
                       revision: int = 0) -> np.ndarray:
        """The operator `name` applied to a per-vertex field (n values for gradient,
        laplace_beltrami and hessian; n x 3 for divergence and weingarten): n x k."""
        request = pb.ApplyOperatorRequest(mesh_id=mesh_id, revision=revision, operator=self._operator_kind(name),
                                          options=pb.FitOptions(degree=degree))
        _encode(np.asarray(field), "<f8", request.field)
        out = self._call(lambda: self._stub.ApplyOperator(request, timeout=self.timeout, metadata=_route(mesh_id)))
        return _decode(out.result, "<f8")

    # ------------------------------------------------------------------ membranes (chapter 6)
    MEMBRANE_QUANTITIES = {"pressure": 1, "stretches": 2, "strain": 3, "stress": 4, "von_mises": 5, "traction": 6}

    def membrane(self, mesh_id: str, deformed=None, young_modulus: float = float("nan"),
                 poisson_ratio: float = float("nan"), quantities: Iterable[str] = ("pressure", "stretches", "von_mises"),
                 revision: int = 0, deformed_revision: int = 0, reference=None, degree: int = 0,
                 progress: ProgressArg = None, **fit_options) -> Dict[str, np.ndarray]:
        """Membrane quantities (6.1-6.2) of a deformed configuration against the reference
        `mesh_id` (at `revision`; 0 = latest): `deformed` is an n x 3 array of positions,
        or the id of a stored mesh of the same topology (with `deformed_revision`), or
        None with `deformed_revision` > 0 for another revision of the reference's mesh.
        `reference`: n x 3 reference positions on the mesh's faces instead of the stored
        ones (after a solve stored its result as the mesh's next revision). young_modulus (E > 0) and poisson_ratio (-1 < nu < 0.5) are required. Returns a
        dict of numpy arrays: pressure (n; inside minus outside), stretches (n x 2),
        strain and stress (n x 3 x 3), von_mises (n), traction (n; n . div sigma, about
        -pressure). degree 0 keeps the server's default (4); `fit_options` are further
        FitOptions fields. `progress`: callable(phase, done, total) or True
        (geomfit.progress): the server's phases, the reference fit's ("fit", ...; none
        when cached) then "membrane" (vertices)."""
        unknown = [q for q in quantities if q not in self.MEMBRANE_QUANTITIES]
        if unknown:
            raise ValueError("unknown quantities %s; choose from %s" % (unknown, sorted(self.MEMBRANE_QUANTITIES)))
        request = pb.ComputeMembraneRequest(mesh_id=mesh_id, revision=revision, young_modulus=young_modulus,
                                            poisson_ratio=poisson_ratio,
                                            quantities=[self.MEMBRANE_QUANTITIES[q] for q in quantities])
        if degree or fit_options:
            request.options.CopyFrom(pb.FitOptions(degree=degree or 4, **fit_options))
        if isinstance(deformed, str):
            request.deformed.CopyFrom(pb.MeshRef(mesh_id=deformed, revision=deformed_revision))
        elif deformed is not None:
            _encode(_positions_array(deformed), "<f8", request.deformed_positions)
        elif deformed_revision:
            request.deformed.CopyFrom(pb.MeshRef(revision=deformed_revision))
        if reference is not None:
            _encode(_positions_array(reference), "<f8", request.reference_positions)

        def run(report):
            out: Dict[str, np.ndarray] = {}
            total = 0
            for chunk in self._stub.ComputeMembrane(request, timeout=self.timeout, metadata=_route(mesh_id)):
                if chunk.HasField("progress"):
                    report(chunk.progress.phase, chunk.progress.done, chunk.progress.total)
                    continue
                if chunk.total_vertices:
                    total = chunk.total_vertices
                lo = chunk.vertex_offset
                for name in self.MEMBRANE_QUANTITIES:
                    field = getattr(chunk, name)
                    if not field.data:
                        continue
                    a = _decode(field, "<f8")
                    if name not in out:
                        out[name] = np.empty((total,) + a.shape[1:], dtype=np.float64)
                    out[name][lo:lo + len(a)] = a
            for name in ("strain", "stress"):
                if name in out:
                    out[name] = out[name].reshape(-1, 3, 3)
            return out
        with reporting(progress) as report:
            request.progress = report is not None
            return self._call(lambda: run(report))

    def membrane_pressure(self, mesh_id: str, deformed=None, young_modulus: float = float("nan"),
                          poisson_ratio: float = float("nan"), progress: ProgressArg = None,
                          **options) -> np.ndarray:
        """The interface pressure p = tr(W tau^) (6.2.10) per vertex, inside minus
        outside, that the membrane's stress balances (membrane()'s arguments, `progress`
        included)."""
        return self.membrane(mesh_id, deformed, young_modulus, poisson_ratio, quantities=("pressure",),
                             progress=progress, **options)["pressure"]

    def start_membrane_solve(self, mesh_id: str, pressure, young_modulus: float, poisson_ratio: float,
                             boundary: str = "", degree: int = 0, solver: str = "", tolerance: float = 0.0,
                             max_iterations: int = 0, max_load_cuts: Optional[int] = None, new_mesh: bool = False,
                             name: str = "", send_displacement: bool = False, revision: int = 0) -> "pb.Job":
        """Starts the pressure-load solve (6.4.1) of the reference membrane `mesh_id`
        under `pressure` (a number or one value per vertex; inside minus outside):
        boundary "clamped" or "free" for open surfaces; degree 0 keeps the default (4);
        tolerance 0 = 1e-10 (relative residual). The deformed surface is stored as a new
        revision of the mesh (new_mesh=True: as a new mesh). Returns the job at once."""
        spec = pb.MembraneSolveJob(mesh_id=mesh_id, revision=revision, young_modulus=young_modulus,
                                   poisson_ratio=poisson_ratio, solver=solver, tolerance=tolerance,
                                   max_iterations=max_iterations, new_mesh=new_mesh, name=name,
                                   send_displacement=send_displacement)
        if np.ndim(pressure) == 0:
            spec.pressure = float(pressure)
        else:
            _encode(np.asarray(pressure, dtype=np.float64).reshape(-1), "<f8", spec.pressure_field)
        if boundary:
            boundaries = {"clamped": pb.MEMBRANE_BOUNDARY_CLAMPED, "free": pb.MEMBRANE_BOUNDARY_FREE}
            if boundary not in boundaries:
                raise ValueError(f"boundary {boundary!r}: expected clamped or free")
            spec.boundary = boundaries[boundary]
        if degree:
            spec.fit.degree = degree
        if max_load_cuts is not None:
            spec.max_load_cuts = max_load_cuts
        return self._call(lambda: self._stub.StartMembraneSolve(spec, timeout=self.timeout))

    def membrane_solve(self, mesh_id: str, pressure, young_modulus: float, poisson_ratio: float,
                       progress: ProgressArg = None, **options) -> Iterator["pb.JobEvent"]:
        """Runs the pressure-load solve (start_membrane_solve's options) and iterates over
        its job events as they come: phase "newton" per Newton iteration (values residual,
        step, load; counts load_step, iteration), "stored" (results: the deformed surface;
        arrays "displacement" with send_displacement=True), then the final event (values
        residual, max_displacement, timings; counts iterations, factorizations). A solve
        that does not converge raises GeomfitError (FAILED_PRECONDITION, its residual
        history) after its final event; closing the iterator early cancels the job.
        `progress`: callable(phase, done, total) or True (geomfit.progress): every event's
        phase and done of total."""
        yield from self._job_events(self.start_membrane_solve(mesh_id, pressure, young_modulus, poisson_ratio,
                                                              **options), progress)
