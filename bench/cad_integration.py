#!/usr/bin/python3
"""Integration over a CAD part with sharp edges (issue 16 item 4).

A gmsh OpenCASCADE part: the rounded rectangle a x b with corner radius f (four
quarter-cylinder fillets along the vertical edges) minus a centred disc of radius
rho, extruded by c. Its sharp edges are the top and bottom outlines and the hole's
rims (90 degree dihedral angles); the fillets meet the flat sides tangentially.
Exact values (closed form):

  cross-section  S = a b - (4 - pi) f^2 - pi rho^2
  outline        L = 2 (a + b) - 8 f + 2 pi f
  area           A = 2 S + c (L + 2 pi rho)
  volume         V = c S

Case "box-hole" is the same part without fillets (f = 0). Each part is meshed by
gmsh (2-D mesh of the boundary, MeshSizeMin = MeshSizeMax = h), the triangles are
oriented consistently outward, and `geomfit integrate --local` is run with
--method linear, with WALF (default settings) and with WALF --feature-angle, at
degrees 2-4. The table gives relative area and volume errors.

Usage (Debian's python3 with python3-numpy; gmsh on PATH, see
scripts/install-bench-deps.sh):

  /usr/bin/python3 bench/cad_integration.py build/clients/cpp/geomfit \
      [--outdir /tmp/geomfit-cad] [--sizes 0.16,0.11,0.08,0.056] [--feature-angle 45]

Exit status 1 if geomfit failed on any mesh, 2 if --feature-angle did not beat both
linear and plain WALF (area and volume) at every size and degree.
"""

import argparse
import math
import os
import subprocess
import sys
from collections import deque

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from external_meshes import compact, read_msh2, signed_volume, write_obj  # noqa: E402

CASES = {
    # name: (a, b, c, rho, f)
    "fillet-box-hole": (2.0, 1.5, 0.8, 0.35, 0.3),
    "box-hole": (2.0, 1.5, 0.8, 0.35, 0.0),
}


def exact(a, b, c, rho, f):
    s = a * b - (4 - math.pi) * f * f - math.pi * rho * rho
    outline = 2 * (a + b) - 8 * f + 2 * math.pi * f
    return 2 * s + c * (outline + 2 * math.pi * rho), c * s


def orient_consistently(F):
    """Flips faces so that every edge is used once in each direction (BFS over the
    edge-adjacency of a closed manifold mesh)."""
    F = F.copy()
    edge_faces = {}
    for i, t in enumerate(F):
        for k in range(3):
            e = (min(t[k], t[(k + 1) % 3]), max(t[k], t[(k + 1) % 3]))
            edge_faces.setdefault(e, []).append(i)
    bad = [e for e, fs in edge_faces.items() if len(fs) != 2]
    if bad:
        raise RuntimeError(f"{len(bad)} edges are not shared by exactly two faces")
    seen = np.zeros(len(F), dtype=bool)
    for start in range(len(F)):
        if seen[start]:
            continue
        seen[start] = True
        queue = deque([start])
        while queue:
            i = queue.popleft()
            t = F[i]
            for k in range(3):
                u, v = t[k], t[(k + 1) % 3]
                for j in edge_faces[(min(u, v), max(u, v))]:
                    if j == i or seen[j]:
                        continue
                    s = F[j]
                    # consistent: the neighbour uses the edge as (v, u)
                    if any(s[m] == u and s[(m + 1) % 3] == v for m in range(3)):
                        F[j] = s[::-1]
                    seen[j] = True
                    queue.append(j)
    return F


def make_part(outdir, name, dims, h):
    a, b, c, rho, f = dims
    stem = os.path.join(outdir, f"{name}_h{h:g}")
    with open(stem + ".geo", "w") as out:
        out.write('SetFactory("OpenCASCADE");\n'
                  f"Rectangle(1) = {{0, 0, 0, {a}, {b}{', ' + str(f) if f > 0 else ''}}};\n"
                  f"Disk(2) = {{{a / 2}, {b / 2}, 0, {rho}}};\n"
                  "BooleanDifference(3) = { Surface{1}; Delete; }{ Surface{2}; Delete; };\n"
                  f"Extrude {{0, 0, {c}}} {{ Surface{{3}}; }}\n"
                  f"Mesh.MeshSizeMax = {h};\nMesh.MeshSizeMin = {h};\n"
                  "Mesh.MeshSizeFromCurvature = 0;\n")
    cmd = ["gmsh", stem + ".geo", "-2", "-format", "msh2", "-o", stem + ".msh"]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{r.stdout}\n{r.stderr}")
    V, F = read_msh2(stem + ".msh")
    V, F, _ = compact(V, F)
    F = orient_consistently(F)
    if signed_volume(V, F) < 0:
        F = F[:, ::-1].copy()
    write_obj(stem + ".obj", V, F)
    return stem + ".obj", len(V), len(F)


FAILURES = []


def integrate(geomfit, mesh, args):
    cmd = [geomfit, "integrate", mesh] + args
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        FAILURES.append((" ".join(cmd), r.returncode, (r.stderr or r.stdout).strip()))
        return None
    vals = dict(line.split("\t") for line in r.stdout.strip().split("\n"))
    return float(vals["area"]), float(vals["volume"])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("geomfit", nargs="?", default="build/clients/cpp/geomfit")
    ap.add_argument("--outdir", default="/tmp/geomfit-cad")
    ap.add_argument("--sizes", default="0.16,0.11,0.08,0.056")
    ap.add_argument("--degrees", default="2,3,4")
    ap.add_argument("--feature-angle", default="45")
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--threads", default="0")
    args = ap.parse_args()
    geomfit = os.path.abspath(args.geomfit)
    os.makedirs(args.outdir, exist_ok=True)
    sizes = [float(s) for s in args.sizes.split(",")]
    degrees = [int(d) for d in args.degrees.split(",")]
    losses = []
    for name in args.cases.split(","):
        dims = CASES[name]
        area, volume = exact(*dims)
        print(f"\n### {name}: a, b, c = {dims[0]}, {dims[1]}, {dims[2]}; hole radius {dims[3]}; "
              f"fillet radius {dims[4]}; exact area {area:.10f}, volume {volume:.10f}\n")
        print("| h | #V | #F | degree | linear area | WALF area | WALF+features area "
              "| linear volume | WALF volume | WALF+features volume |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for h in sizes:
            mesh, nv, nf = make_part(args.outdir, name, dims, h)
            common = ["--threads", args.threads]
            lin = integrate(geomfit, mesh, ["--method", "linear"] + common)
            for d in degrees:
                walf = integrate(geomfit, mesh, ["--degree", str(d)] + common)
                feat = integrate(geomfit, mesh, ["--degree", str(d), "--feature-angle", args.feature_angle] + common)
                if lin is None or walf is None or feat is None:
                    print(f"| {h:g} | {nv} | {nf} | {d} | geomfit FAILED: {FAILURES[-1][2]} | | | | | |")
                    continue
                e = [abs(r[0] - area) / area for r in (lin, walf, feat)]
                v = [abs(r[1] - volume) / volume for r in (lin, walf, feat)]
                print(f"| {h:g} | {nv} | {nf} | {d} | " + " | ".join(f"{x:.2e}" for x in e + v) + " |", flush=True)
                if not (e[2] < min(e[0], e[1]) and v[2] < min(v[0], v[1])):
                    losses.append((name, h, d))
    if FAILURES:
        print("\n## geomfit FAILURES\n")
        for cmd, rc, msg in FAILURES:
            print(f"- exit {rc}: `{msg}` from `{cmd}`")
        return 1
    if losses:
        print(f"\n--feature-angle did not beat both linear and WALF at: {losses}")
        return 2
    print("\n--feature-angle beats linear and WALF (area and volume) at every size and degree.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
