"""Mesh file readers: geomfit's C++ readers through the native module when it is built,
numpy readers of the same formats otherwise (OBJ, OFF, PLY ascii and binary little
endian, STL ascii and binary with bitwise-equal corners welded)."""
import os
import struct
from typing import List, Sequence, Tuple

import numpy as np

try:
    from geomfit import _native
except ImportError:
    _native = None

MeshArrays = Tuple[np.ndarray, np.ndarray]
FORMATS = (".obj", ".off", ".ply", ".stl")


def read_mesh_file(path: str, native: bool = True) -> MeshArrays:
    """Reads OBJ, OFF, PLY (ascii, binary little endian) or STL (ascii, binary):
    (positions #V x 3 float64, faces #F x 3 int32, or #F x 4 with -1 padding triangles
    when there are quads). `native=False` uses the numpy readers even when the C++ ones
    are available. Raises ValueError naming the file (and line) at fault."""
    ext = os.path.splitext(path)[1].lower()
    if ext not in FORMATS:
        raise ValueError("%s: unknown mesh format %r (read: %s)" % (path, ext, ", ".join(FORMATS)))
    if not os.path.isfile(path):
        raise FileNotFoundError(path)
    if native and _native is not None:
        positions, faces = _native.read_mesh(path)
        return np.ascontiguousarray(positions), np.ascontiguousarray(faces, dtype=np.int32)
    with open(path, "rb") as f:
        data = f.read()
    reader = {".obj": _read_obj, ".off": _read_off, ".ply": _read_ply, ".stl": _read_stl}[ext]
    positions, faces = reader(data, path)
    return _checked(positions, faces, path)


def _checked(positions: np.ndarray, faces: Sequence[Sequence[int]], path: str) -> MeshArrays:
    """Arrays from the parsed lists; faces of 3 or 4 indices of existing vertices."""
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    if isinstance(faces, np.ndarray) and faces.ndim == 2:
        out = faces.astype(np.int32)
    else:
        for i, f in enumerate(faces):
            if len(f) not in (3, 4):
                raise ValueError("%s: face %d has %d vertices (3 or 4 supported)" % (path, i, len(f)))
        quads = any(len(f) == 4 for f in faces)
        out = np.full((len(faces), 4 if quads else 3), -1, dtype=np.int32)
        for i, f in enumerate(faces):
            out[i, :len(f)] = f
    bad = np.nonzero(((out < 0) & ~((np.arange(out.shape[1]) == 3) & (out == -1))).any(axis=1)
                     | (out >= len(positions)).any(axis=1))[0]
    if len(bad):
        raise ValueError("%s: face %d names a vertex that does not exist (%d vertices)"
                         % (path, bad[0], len(positions)))
    return positions, out


def _text_lines(data: bytes) -> List[str]:
    return data.decode("utf-8", errors="replace").splitlines()


def _read_obj(data: bytes, path: str):
    verts: List[List[float]] = []
    faces: List[List[int]] = []
    for n, line in enumerate(_text_lines(data), 1):
        parts = line.split()
        if not parts:
            continue
        try:
            if parts[0] == "v":
                verts.append([float(x) for x in parts[1:4]])
            elif parts[0] == "f":
                idx = [int(p.split("/")[0]) for p in parts[1:]]
                faces.append([i - 1 if i > 0 else len(verts) + i for i in idx])
        except ValueError as e:
            raise ValueError("%s:%d: %s" % (path, n, e)) from None
    return verts, faces


def _read_off(data: bytes, path: str):
    tokens = [t for t in (ln.split("#")[0].split() for ln in _text_lines(data)) if t]
    if not tokens or not tokens[0][0].endswith("OFF"):
        raise ValueError("%s: not an OFF file" % path)
    header = tokens[0]
    counts, start = (header[1:], 1) if len(header) > 1 else (tokens[1], 2)
    nv, nf = int(counts[0]), int(counts[1])
    if len(tokens) < start + nv + nf:
        raise ValueError("%s: %d vertices and %d faces announced, file ends early" % (path, nv, nf))
    verts = [[float(x) for x in t[:3]] for t in tokens[start:start + nv]]
    faces = [[int(x) for x in t[1:1 + int(t[0])]] for t in tokens[start + nv:start + nv + nf]]
    return verts, faces


_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def _read_ply(data: bytes, path: str):
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise ValueError("%s: not a PLY file" % path)
    body = data[data.index(b"\n", end) + 1:]
    fmt, elements = "", []  # elements: [name, count, [(prop name, dtype, list count dtype or None)]]
    for line in data[:end].decode("ascii", errors="replace").splitlines():
        p = line.split()
        if not p:
            continue
        if p[0] == "format":
            fmt = p[1]
        elif p[0] == "element":
            elements.append([p[1], int(p[2]), []])
        elif p[0] == "property" and elements:
            if p[1] == "list":
                elements[-1][2].append((p[4], _PLY_TYPES[p[3]], _PLY_TYPES[p[2]]))
            else:
                elements[-1][2].append((p[2], _PLY_TYPES[p[1]], None))
    if fmt not in ("ascii", "binary_little_endian"):
        raise ValueError("%s: PLY format %r not supported (ascii, binary_little_endian)" % (path, fmt))
    verts, faces = np.zeros((0, 3)), []
    if fmt == "ascii":
        tokens, i = body.split(), 0
        for name, count, props in elements:
            rows = []
            for _ in range(count):
                row = {}
                for pname, _, list_type in props:
                    if list_type:
                        k = int(tokens[i])
                        row[pname] = [int(float(x)) for x in tokens[i + 1:i + 1 + k]]
                        i += 1 + k
                    else:
                        row[pname] = float(tokens[i])
                        i += 1
                rows.append(row)
            if name == "vertex":
                verts = [[r["x"], r["y"], r["z"]] for r in rows]
            elif name == "face":
                faces = [r.get("vertex_indices", r.get("vertex_index")) for r in rows]
        return verts, faces
    offset = 0
    for name, count, props in elements:
        if all(lt is None for _, _, lt in props):  # fixed-size rows: one numpy view
            dtype = np.dtype([(pname, "<" + t) for pname, t, _ in props])
            rows = np.frombuffer(body, dtype, count, offset)
            offset += dtype.itemsize * count
            if name == "vertex":
                verts = np.stack([rows["x"], rows["y"], rows["z"]], axis=1).astype(np.float64)
            continue
        rows = []
        for _ in range(count):
            row = {}
            for pname, t, list_type in props:
                if list_type:
                    k = int(np.frombuffer(body, "<" + list_type, 1, offset)[0])
                    offset += np.dtype(list_type).itemsize
                    row[pname] = np.frombuffer(body, "<" + t, k, offset).tolist()
                    offset += np.dtype(t).itemsize * k
                else:
                    row[pname] = np.frombuffer(body, "<" + t, 1, offset)[0]
                    offset += np.dtype(t).itemsize
            rows.append(row)
        if name == "face":
            faces = [r.get("vertex_indices", r.get("vertex_index")) for r in rows]
    return verts, faces


def _read_stl(data: bytes, path: str):
    if len(data) >= 84 and len(data) == 84 + 50 * struct.unpack_from("<I", data, 80)[0]:
        n = struct.unpack_from("<I", data, 80)[0]
        tri = np.frombuffer(data, np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]), n, 84)
        corners = tri["v"].reshape(-1, 3)
    else:
        corners = np.array([[float(x) for x in ln.split()[1:4]] for ln in _text_lines(data)
                            if ln.strip().startswith("vertex")], dtype=np.float64).reshape(-1, 3)
        if len(corners) % 3:
            raise ValueError("%s: %d vertex lines, not a multiple of 3" % (path, len(corners)))
    # Weld bitwise-equal corners, numbered in order of first appearance (as the C++ reader).
    keys = np.ascontiguousarray(corners).view(np.dtype((np.void, corners.dtype.itemsize * 3))).ravel()
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return corners[first[order]].astype(np.float64), rank[inverse].reshape(-1, 3)
