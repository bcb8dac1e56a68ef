"""Interop with meshio (Debian: python3-meshio): meshes and per-vertex results."""
from typing import Any, Dict, Optional, Tuple

import numpy as np


def _meshio():
    try:
        import meshio
    except ImportError as e:
        raise ImportError("geomfit: this helper needs meshio (Debian: python3-meshio)") from e
    return meshio


def from_meshio(mesh: Any) -> Tuple[np.ndarray, np.ndarray]:
    """(positions #V x 3 float64, faces int32) of a meshio.Mesh's triangle and quad
    cells: #F x 3 for triangles only, else #F x 4 with -1 padding triangles. Other cell
    types (lines, vertices, volumes) are ignored; ValueError if there is no surface cell."""
    positions = np.ascontiguousarray(np.asarray(mesh.points, dtype=np.float64)[:, :3])
    if positions.shape[1] == 2:
        positions = np.hstack([positions, np.zeros((len(positions), 1))])
    blocks = [np.asarray(c.data, dtype=np.int64) for c in mesh.cells if c.type in ("triangle", "quad")]
    if not blocks:
        raise ValueError("from_meshio: the mesh has no triangle or quad cells (%s)"
                         % sorted({c.type for c in mesh.cells}))
    if all(b.shape[1] == 3 for b in blocks):
        return positions, np.concatenate(blocks).astype(np.int32)
    padded = [np.hstack([b, np.full((len(b), 1), -1)]) if b.shape[1] == 3 else b for b in blocks]
    return positions, np.concatenate(padded).astype(np.int32)


def to_meshio(positions: np.ndarray, faces: np.ndarray, point_data: Optional[Dict[str, np.ndarray]] = None,
              differentials: Any = None) -> Any:
    """A meshio.Mesh with triangle and quad cells (-1 padding in a 4-column faces array
    marks triangles). `point_data`: per-vertex arrays; `differentials`: a
    geomfit.Differentials whose arrays are added (Normals, MeanCurvature,
    GaussianCurvature, k1, k2, Direction1, Direction2, CurvatureTensor)."""
    meshio = _meshio()
    f = np.asarray(faces)
    cells = []
    if f.shape[1] == 3:
        cells.append(("triangle", f.astype(np.int64)))
    else:
        tri = f[:, 3] < 0
        if tri.any():
            cells.append(("triangle", f[tri, :3].astype(np.int64)))
        if (~tri).any():
            cells.append(("quad", f[~tri].astype(np.int64)))
    data = dict(point_data or {})
    if differentials is not None:
        names = {"normals": "Normals", "mean": "MeanCurvature", "gaussian": "GaussianCurvature", "k1": "k1",
                 "k2": "k2", "dir1": "Direction1", "dir2": "Direction2", "tensor": "CurvatureTensor"}
        for attr, name in names.items():
            value = getattr(differentials, attr, None)
            if value is not None:
                data[name] = np.asarray(value)
    return meshio.Mesh(np.asarray(positions, dtype=np.float64), cells, point_data=data)
