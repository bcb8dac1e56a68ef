#!/usr/bin/python3
"""Convergence study of geomfit on torus meshes its tests have never seen.

Mirrors the dissertation's Section 3.3 (GAMBIT meshes and MATLAB isosurface
meshes of a torus) with meshes from two independent generators:

  a   unstructured triangulations from gmsh (OpenCASCADE torus, 2-D mesh only,
      mesh size h = 0.16, 0.08, 0.04, 0.02), every vertex projected onto the
      torus (closest point), so the input error is at machine precision;
  b1  marching-cubes meshes (skimage.measure.marching_cubes, Lewiner) of the
      implicit torus on N^3 grids, N = 32, 64, 128, 256, vertices projected
      onto the torus (poorly shaped but exact);
  b2  the same marching-cubes meshes with the raw vertices (O(h^2) position
      error, the dissertation's "noisy" case), run with --noise on, with
      --approximate and rings d/2+1, and with geomfit's default settings.

Torus: centre circle radius R = 1 in the xy-plane, tube radius r = 0.3. Faces
are oriented outward (positive enclosed volume) and checked for consistent
orientation and closed, manifold connectivity before geomfit sees them.

For every mesh and degree, `geomfit curvature --local MESH --degree D ...
--output F.tsv` is run and compared with the exact torus:
  normals  L2 = sqrt(mean |n~ - n|^2),  Linf = max |n~ - n|
  H, K     L2 = |k~ - k|_2 / |k|_2,      Linf = max |k~ - k| / max |k|
For b2 the exact quantities are evaluated at the closest torus point of each
raw vertex. Convergence rates: least-squares slope of -log(error) against
log(average edge length) ("fit"), and (3.3.1) log2(e_1 / e_4) / 3.

Usage (Debian's python3 with python3-numpy and python3-skimage; gmsh on PATH;
`bash scripts/install-bench-deps.sh` installs them):

  /usr/bin/python3 bench/external_meshes.py build/clients/cpp/geomfit \
      [--outdir /tmp/geomfit-external] [--families a,b1,b2] [--levels 4]

Needs nothing but numpy (and skimage for the b families); meshes are read and
written by the small readers/writers below. Exit status 1 if geomfit failed on
any mesh (the failing commands and messages are printed at the end).

geomfit refuses a whole mesh when a face has |2 area| <= 1e-14 x bbox-diagonal^2
("face N has zero area"); the 256^3 marching-cubes meshes contain 16 such
well-shaped but tiny (edges ~3e-7) faces. The failure is kept in the tables and,
unless --no-weld is given, that level is re-run on a copy in which the shortest
edge of each such face is collapsed (rows marked "4w"; rates use them).
"""

import argparse
import math
import os
import shutil
import subprocess
import sys
import time

import numpy as np

R_CENTRE = 1.0
R_TUBE = 0.3
GMSH_SIZES = [0.16, 0.08, 0.04, 0.02]
MC_GRIDS = [32, 64, 128, 256]
MC_BOX = ((-1.4, 1.4), (-1.4, 1.4), (-0.4, 0.4))


# ----------------------------------------------------------------------------
# Exact torus
# ----------------------------------------------------------------------------

def torus_closest(p):
    """Closest points on the torus and the angles (u, v) there."""
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    u = np.arctan2(y, x)
    rho = np.hypot(x, y)
    v = np.arctan2(z, rho - R_CENTRE)
    cu, su, cv, sv = np.cos(u), np.sin(u), np.cos(v), np.sin(v)
    q = np.column_stack(((R_CENTRE + R_TUBE * cv) * cu,
                         (R_CENTRE + R_TUBE * cv) * su,
                         R_TUBE * sv))
    return q, u, v


def torus_exact(p):
    """Exact normal, H, K, k1, k2 at the closest torus points of p."""
    _, u, v = torus_closest(p)
    cu, su, cv, sv = np.cos(u), np.sin(u), np.cos(v), np.sin(v)
    n = np.column_stack((cv * cu, cv * su, sv))
    k_tube = np.full_like(v, 1.0 / R_TUBE)
    k_ring = cv / (R_CENTRE + R_TUBE * cv)
    return {"n": n, "H": 0.5 * (k_tube + k_ring), "K": k_tube * k_ring,
            "k1": np.maximum(k_tube, k_ring), "k2": np.minimum(k_tube, k_ring)}


def distance_to_torus(p):
    rho = np.hypot(p[:, 0], p[:, 1])
    return np.abs(np.hypot(rho - R_CENTRE, p[:, 2]) - R_TUBE)


# ----------------------------------------------------------------------------
# Mesh utilities (numpy only)
# ----------------------------------------------------------------------------

def signed_volume(V, F):
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0


def triangle_areas(V, F):
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


def check_closed_oriented(F, nv):
    """Each directed edge exactly once and its reverse exactly once (closed,
    manifold, consistently oriented). Returns (ok, message)."""
    e = np.concatenate((F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]])).astype(np.int64)
    key = e[:, 0] * nv + e[:, 1]
    rkey = e[:, 1] * nv + e[:, 0]
    uk, cnt = np.unique(key, return_counts=True)
    if (cnt > 1).any():
        return False, f"{int((cnt > 1).sum())} directed edges used twice (inconsistent orientation or non-manifold)"
    missing = ~np.isin(rkey, uk)
    if missing.any():
        return False, f"{int(missing.sum())} half-edges without a twin (open or non-manifold)"
    nedges = len(uk) // 2
    euler = nv - nedges + len(F)
    if euler != 0:
        return False, f"Euler characteristic {euler} != 0 (not a torus)"
    return True, "closed, manifold, consistently oriented, genus 1"


def unique_edges(F):
    e = np.concatenate((F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]))
    e = np.sort(e, axis=1)
    return np.unique(e, axis=0)


def mesh_stats(V, F):
    E = unique_edges(F)
    lens = np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]

    def ang(p, q, r):
        u, w = q - p, r - p
        cosang = np.einsum("ij,ij->i", u, w) / (np.linalg.norm(u, axis=1) * np.linalg.norm(w, axis=1))
        return np.degrees(np.arccos(np.clip(cosang, -1.0, 1.0)))

    angles = np.concatenate((ang(a, b, c), ang(b, c, a), ang(c, a, b)))
    valence = np.bincount(E.ravel(), minlength=len(V))
    return {"nv": len(V), "nf": len(F), "h": float(lens.mean()),
            "min_angle": float(angles.min()), "max_angle": float(angles.max()),
            "val_min": int(valence.min()), "val_max": int(valence.max())}


def orient_outward(V, F):
    vol = signed_volume(V, F)
    flipped = vol < 0
    if flipped:
        F = F[:, ::-1].copy()
    return F, flipped, abs(vol)


def write_obj(path, V, F):
    with open(path, "w") as f:
        f.write("# geomfit bench/external_meshes.py\n")
        np.savetxt(f, V, fmt="v %.17g %.17g %.17g")
        np.savetxt(f, F + 1, fmt="f %d %d %d")


def read_msh2(path):
    """Minimal ASCII MSH 2.2 reader: nodes and 3-node triangles (type 2)."""
    with open(path) as f:
        lines = f.read().split("\n")
    i = 0
    nodes, tris = None, []
    ids = None
    while i < len(lines):
        s = lines[i].strip()
        if s == "$MeshFormat":
            ver = lines[i + 1].split()
            if not ver[0].startswith("2") or ver[1] != "0":
                raise ValueError(f"{path}: expected ASCII MSH 2.x, got {lines[i + 1]!r}")
            i += 2
        elif s == "$Nodes":
            n = int(lines[i + 1])
            arr = np.array([l.split() for l in lines[i + 2:i + 2 + n]], dtype=float)
            ids = arr[:, 0].astype(np.int64)
            nodes = arr[:, 1:4]
            i += 2 + n
        elif s == "$Elements":
            n = int(lines[i + 1])
            for l in lines[i + 2:i + 2 + n]:
                t = l.split()
                if t[1] == "2":
                    ntag = int(t[2])
                    tris.append([int(x) for x in t[3 + ntag:6 + ntag]])
                elif t[1] not in ("1", "15"):
                    raise ValueError(f"{path}: unexpected element type {t[1]}")
            i += 2 + n
        else:
            i += 1
    tris = np.array(tris, dtype=np.int64)
    lookup = np.full(ids.max() + 1, -1, dtype=np.int64)
    lookup[ids] = np.arange(len(ids))
    return nodes, lookup[tris]


def compact(V, F):
    """Drop unreferenced vertices; return (V, F, number removed)."""
    used = np.zeros(len(V), dtype=bool)
    used[F.ravel()] = True
    remap = np.cumsum(used) - 1
    return V[used], remap[F], int((~used).sum())


def geomfit_zero_area_faces(V, F):
    """Faces geomfit's ValidateGeometry rejects ("face %d has zero area"):
    |2 * area| <= 1e-14 * (bounding-box diagonal)^2 (core/mesh/topology.cc)."""
    tiny = 1e-14 * max(float(np.sum((V.max(0) - V.min(0)) ** 2)), 1e-300)
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    area2 = np.linalg.norm(np.cross(a, b) + np.cross(b, c) + np.cross(c, a), axis=1)
    return np.nonzero(area2 <= tiny)[0]


def weld_tiny_faces(V, F):
    """Explicit, reported work-around for geomfit's zero-area rejection: collapse
    the shortest edge of every face geomfit would reject (merged vertex at the
    mean position), drop the faces that become degenerate, repeat until none.
    Returns (V, F, #edges collapsed, #faces removed)."""
    collapsed = removed = 0
    while True:
        bad = geomfit_zero_area_faces(V, F)
        if len(bad) == 0:
            return V, F, collapsed, removed
        parent = np.arange(len(V))

        def find(i):
            while parent[i] != i:
                parent[i] = parent[parent[i]]
                i = parent[i]
            return i
        for f in bad:
            t = F[f]
            lens = [np.linalg.norm(V[t[(k + 1) % 3]] - V[t[k]]) for k in range(3)]
            k = int(np.argmin(lens))
            ra, rb = find(t[k]), find(t[(k + 1) % 3])
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)
                collapsed += 1
        root = np.array([find(i) for i in range(len(V))])
        sums = np.zeros_like(V)
        np.add.at(sums, root, V)
        cnt = np.bincount(root, minlength=len(V)).astype(float)
        Vn = V.copy()
        m = cnt > 0
        Vn[m] = sums[m] / cnt[m, None]
        F = root[F]
        keep = (F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 2] != F[:, 0])
        removed += int((~keep).sum())
        F = F[keep]
        V, F, _ = compact(Vn, F)


# ----------------------------------------------------------------------------
# Mesh generation
# ----------------------------------------------------------------------------

def make_gmsh(outdir, level, h, log):
    geo = os.path.join(outdir, f"gmsh_L{level}.geo")
    msh = os.path.join(outdir, f"gmsh_L{level}.msh")
    with open(geo, "w") as f:
        f.write('SetFactory("OpenCASCADE");\n'
                f"Torus(1) = {{0, 0, 0, {R_CENTRE}, {R_TUBE}}};\n"
                f"Mesh.MeshSizeMax = {h};\nMesh.MeshSizeMin = {h};\n"
                "Mesh.MeshSizeFromCurvature = 0;\n")
    cmd = ["gmsh", geo, "-2", "-format", "msh2", "-o", msh]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{r.stdout}\n{r.stderr}")
    V, F = read_msh2(msh)
    V, F, unref = compact(V, F)
    dmax_before = float(distance_to_torus(V).max())
    V = torus_closest(V)[0]
    F, flipped, vol = orient_outward(V, F)
    ok, msg = check_closed_oriented(F, len(V))
    if not ok:
        raise RuntimeError(f"gmsh level {level}: {msg}")
    path = os.path.join(outdir, f"gmsh_L{level}.obj")
    write_obj(path, V, F)
    log(f"  gmsh L{level} h={h}: {len(V)} v, {len(F)} f, unreferenced removed {unref}, "
        f"max dist before projection {dmax_before:.2e}, flipped={flipped}, "
        f"volume {vol:.6f} (exact {2 * math.pi**2 * R_CENTRE * R_TUBE**2:.6f}), {msg}")
    return {"exact": path, "V": V, "F": F}


def make_mc(outdir, n, log, weld=False):
    from skimage import measure
    (x0, x1), (y0, y1), (z0, z1) = MC_BOX
    xs, ys, zs = np.linspace(x0, x1, n), np.linspace(y0, y1, n), np.linspace(z0, z1, n)
    X, Y, Z = np.meshgrid(xs, ys, zs, indexing="ij")
    vol = (np.sqrt(X * X + Y * Y) - R_CENTRE) ** 2 + Z * Z - R_TUBE ** 2
    del X, Y, Z
    exact_zero = int((vol == 0).sum())
    sp = (xs[1] - xs[0], ys[1] - ys[0], zs[1] - zs[0])
    V, F, _, _ = measure.marching_cubes(vol, level=0.0, spacing=sp)
    del vol
    V = V.astype(np.float64) + np.array([x0, y0, z0])
    F = F.astype(np.int64)
    nf0, nv0 = len(F), len(V)
    # exactly degenerate triangles: repeated index or zero area
    rep = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0])
    zero = triangle_areas(V, F) == 0.0
    bad = rep | zero
    F = F[~bad]
    V, F, unref = compact(V, F)
    nreject = len(geomfit_zero_area_faces(V, F))
    # coincident vertex positions that remain (would break connectivity)
    _, inv_cnt = np.unique(V, axis=0, return_counts=True)
    dup = int((inv_cnt > 1).sum())
    F, flipped, volume = orient_outward(V, F)
    ok, msg = check_closed_oriented(F, len(V))
    dist = distance_to_torus(V)
    info = {"grid": n, "spacing": sp, "nv_raw": nv0, "nf_raw": nf0,
            "degenerate_removed": int(bad.sum()), "unreferenced_removed": unref,
            "dup_positions": dup, "exact_zero_samples": exact_zero,
            "pos_L2": float(np.sqrt(np.mean(dist ** 2))), "pos_Linf": float(dist.max()),
            "geomfit_reject": nreject}
    # independent baseline: area-weighted vertex normals of the raw mesh
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    N = np.zeros_like(V)
    for k in range(3):
        np.add.at(N, F[:, k], fn)
    N /= np.linalg.norm(N, axis=1)[:, None]
    dn = np.linalg.norm(N - torus_exact(V)["n"], axis=1)
    info["awn_L2"], info["awn_Linf"] = float(np.sqrt(np.mean(dn ** 2))), float(dn.max())
    log(f"  MC {n}^3 spacing ({sp[0]:.4g},{sp[1]:.4g},{sp[2]:.4g}): {nv0} v, {nf0} f raw; "
        f"removed {info['degenerate_removed']} degenerate faces, {unref} unreferenced vertices; "
        f"{dup} coincident positions left; grid samples exactly 0: {exact_zero}; "
        f"flipped={flipped}; volume {volume:.6f}; {msg}; "
        f"{nreject} faces below geomfit's zero-area threshold")
    if not ok:
        log(f"  WARNING: MC {n}^3 mesh is not a closed oriented torus: {msg}")
    raw = os.path.join(outdir, f"mc{n}_raw.obj")
    write_obj(raw, V, F)
    Vp = torus_closest(V)[0]
    proj = os.path.join(outdir, f"mc{n}_proj.obj")
    write_obj(proj, Vp, F)
    res = {"raw": raw, "exact": proj, "V": V, "Vp": Vp, "F": F, "info": info, "welded": None}
    if weld and (nreject or len(geomfit_zero_area_faces(Vp, F))):
        Vw, Fw, ncol, nrem = weld_tiny_faces(V, F)
        Vwp = torus_closest(Vw)[0]
        left = len(geomfit_zero_area_faces(Vwp, Fw))
        okw, msgw = check_closed_oriented(Fw, len(Vw))
        log(f"  MC {n}^3 WELDED copy (work-around for geomfit's zero-area rejection): collapsed "
            f"{ncol} edges, removed {nrem} faces -> {len(Vw)} v, {len(Fw)} f; {msgw}; "
            f"projected copy still has {left} faces below the threshold")
        rw = os.path.join(outdir, f"mc{n}_welded_raw.obj")
        pw = os.path.join(outdir, f"mc{n}_welded_proj.obj")
        write_obj(rw, Vw, Fw)
        write_obj(pw, Vwp, Fw)
        res["welded"] = {"raw": rw, "exact": pw, "V": Vw, "Vp": Vwp, "F": Fw,
                         "collapsed": ncol, "removed": nrem}
    return res


# ----------------------------------------------------------------------------
# geomfit runs and error measures
# ----------------------------------------------------------------------------

FAILURES = []


def run_geomfit(geomfit, mesh, out, degree, extra, threads):
    cmd = [geomfit, "curvature", "--local", mesh, "--degree", str(degree),
           "--threads", str(threads), "--output", out] + extra
    t0 = time.time()
    r = subprocess.run(cmd, capture_output=True, text=True)
    dt = time.time() - t0
    if r.returncode != 0:
        FAILURES.append((" ".join(cmd), r.returncode, (r.stderr or r.stdout).strip()))
        return None, dt
    data = np.loadtxt(out, ndmin=2)
    return data, dt


def errors(data, P):
    ex = torus_exact(P)
    res = {}
    dn = np.linalg.norm(data[:, 0:3] - ex["n"], axis=1)
    res["nL2"] = float(np.sqrt(np.mean(dn ** 2)))
    res["nLinf"] = float(dn.max())
    for name, col in (("H", 3), ("K", 4)):
        d = data[:, col] - ex[name]
        res[name + "L2"] = float(np.linalg.norm(d) / np.linalg.norm(ex[name]))
        res[name + "Linf"] = float(np.abs(d).max() / np.abs(ex[name]).max())
    res["nan"] = int(np.isnan(data[:, :5]).any(axis=1).sum())
    deg = data[:, 13].astype(int)
    flags = data[:, 15].astype(int)
    res["deg_min"] = int(deg.min())
    res["deg_lt"] = int((deg < res.get("_d", 0)).sum())
    res["pts_mean"] = float(data[:, 14].mean())
    res["flag_few"] = int(((flags & 1) != 0).sum())
    res["flag_down"] = int(((flags & 2) != 0).sum())
    res["flag_other"] = int(((flags & ~3) != 0).sum())
    res["deg"] = deg
    return res


def rates(hs, es):
    hs, es = np.asarray(hs, float), np.asarray(es, float)
    if len(es) < 2 or (es <= 0).any() or not np.isfinite(es).all():
        return float("nan"), float("nan")
    slope = np.polyfit(np.log(hs), np.log(es), 1)[0]
    r331 = math.log2(es[0] / es[-1]) / (len(es) - 1)
    return float(slope), float(r331)


def fmt(x):
    return "nan" if not np.isfinite(x) else f"{x:.2e}"


def study(name, meshes, P_list, hs, geomfit, degrees, extra, threads, outdir, print_, fallbacks=None):
    """fallbacks[i] = (mesh, P, h) used, in a row marked 'w', when geomfit fails on meshes[i]."""
    fallbacks = fallbacks or [None] * len(meshes)
    print_(f"\n### {name}\n")
    cols = ["nL2", "nLinf", "HL2", "HLinf", "KL2", "KLinf"]
    hdr = "| degree | level | #V | h | n L2 | n Linf | H L2 | H Linf | K L2 | K Linf | deg<d | flags few/down | time s |"
    print_(hdr)
    print_("|" + "---|" * (hdr.count("|") - 1))
    rate_rows = []
    for d in degrees:
        per = []
        used_h = []
        for lvl, (mesh, P, h) in enumerate(zip(meshes, P_list, hs), 1):
            ex = extra(d) if callable(extra) else extra
            out = os.path.join(outdir, f"out_{os.path.basename(mesh)[:-4]}_d{d}_{'_'.join(ex).replace('--', '') or 'default'}.tsv")
            data, dt = run_geomfit(geomfit, mesh, out, d, ex, threads)
            if data is None:
                print_(f"| {d} | {lvl} | {len(P)} | {h:.4f} | geomfit FAILED: {FAILURES[-1][2]} | | | | | | | |")
                if fallbacks[lvl - 1] is None:
                    per.append(None)
                    used_h.append(h)
                    continue
                mesh, P, h = fallbacks[lvl - 1]
                out = out[:-4] + "_welded.tsv"
                data, dt = run_geomfit(geomfit, mesh, out, d, ex, threads)
                lvl = f"{lvl}w"
                if data is None:
                    print_(f"| {d} | {lvl} | {len(P)} | {h:.4f} | geomfit FAILED: {FAILURES[-1][2]} | | | | | | | |")
                    per.append(None)
                    used_h.append(h)
                    continue
            used_h.append(h)
            e = errors(data, P)
            e["deg_lt"] = int((e["deg"] < d).sum())
            per.append(e)
            print_(f"| {d} | {lvl} | {len(P)} | {h:.4f} | " + " | ".join(fmt(e[c]) for c in cols)
                   + f" | {e['deg_lt']} | {e['flag_few']}/{e['flag_down']} | {dt:.2f} |"
                   + (f" NaN rows: {e['nan']}" if e["nan"] else ""))
            try:
                os.remove(out)
            except OSError:
                pass
        ok = [i for i, e in enumerate(per) if e is not None]
        row = []
        for c in cols:
            if len(ok) == len(per):
                s, r = rates(used_h, [per[i][c] for i in ok])
                row.append((s, r))
            else:
                row.append((float("nan"), float("nan")))
        rate_rows.append((d, row))
    print_(f"\nConvergence rates, {name}: least-squares slope of log(error) vs log(h) / (3.3.1) log2(e1/e4)/3\n")
    print_("| degree | n L2 | n Linf | H L2 | H Linf | K L2 | K Linf |")
    print_("|---|---|---|---|---|---|---|")
    for d, row in rate_rows:
        print_(f"| {d} | " + " | ".join(f"{s:.2f} / {r:.2f}" for s, r in row) + " |")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("geomfit", nargs="?", default="build/clients/cpp/geomfit", help="path of the geomfit CLI")
    ap.add_argument("--outdir", default="/tmp/geomfit-external", help="where meshes and outputs go")
    ap.add_argument("--families", default="a,b1,b2", help="comma list of a, b1, b2")
    ap.add_argument("--levels", type=int, default=4, help="number of levels (1..4)")
    ap.add_argument("--threads", type=int, default=0, help="geomfit --threads (0 = all cores)")
    ap.add_argument("--no-weld", dest="weld", action="store_false",
                    help="no welded fallback: when geomfit rejects a marching-cubes mesh for a tiny "
                         "(non-degenerate) face, leave that level failed instead of re-running it on a "
                         "copy whose tiny faces are collapsed (rows marked 'w')")
    ap.add_argument("--report", default=None, help="also write the tables to this markdown file")
    args = ap.parse_args()

    geomfit = os.path.abspath(args.geomfit)
    if not os.access(geomfit, os.X_OK):
        sys.exit(f"external_meshes: {geomfit} is not an executable geomfit")
    os.makedirs(args.outdir, exist_ok=True)
    fams = set(args.families.split(","))
    if "a" in fams and shutil.which("gmsh") is None:
        sys.exit("external_meshes: gmsh not found on PATH (bash scripts/install-bench-deps.sh)")
    if fams & {"b1", "b2"}:
        try:
            import skimage.measure  # noqa: F401
        except ImportError:
            sys.exit("external_meshes: skimage missing; use Debian's /usr/bin/python3 with python3-skimage "
                     "(bash scripts/install-bench-deps.sh)")
    lines = []

    def print_(s=""):
        print(s, flush=True)
        lines.append(s)

    t_start = time.time()
    print_(f"# geomfit on external torus meshes (R = {R_CENTRE}, r = {R_TUBE})\n")
    print_("Mesh generation:\n")
    print_("```")
    if "a" in fams:
        gm = [make_gmsh(args.outdir, i + 1, h, print_) for i, h in enumerate(GMSH_SIZES[:args.levels])]
    if fams & {"b1", "b2"}:
        mc = [make_mc(args.outdir, n, print_, args.weld) for n in MC_GRIDS[:args.levels]]
    print_("```")
    print_(f"(mesh generation {time.time() - t_start:.1f} s)")

    print_("\nMeshes (h = average edge length; angles in degrees):\n")
    print_("| family | level | #V | #F | h | min angle | max angle | valence |")
    print_("|---|---|---|---|---|---|---|---|")
    if "a" in fams:
        for i, m in enumerate(gm, 1):
            m["stats"] = mesh_stats(m["V"], m["F"])
            s = m["stats"]
            print_(f"| gmsh h={GMSH_SIZES[i - 1]} | {i} | {s['nv']} | {s['nf']} | {s['h']:.4f} | {s['min_angle']:.2f} | {s['max_angle']:.2f} | {s['val_min']}-{s['val_max']} |")
    if fams & {"b1", "b2"}:
        for i, m in enumerate(mc, 1):
            m["stats"] = mesh_stats(m["Vp"], m["F"])
            m["stats_raw"] = mesh_stats(m["V"], m["F"])
            if m["welded"] is not None:
                w = m["welded"]
                w["h_proj"] = mesh_stats(w["Vp"], w["F"])["h"]
                w["h_raw"] = mesh_stats(w["V"], w["F"])["h"]
            s = m["stats"]
            print_(f"| MC {MC_GRIDS[i - 1]}^3 projected | {i} | {s['nv']} | {s['nf']} | {s['h']:.4f} | {s['min_angle']:.2f} | {s['max_angle']:.2f} | {s['val_min']}-{s['val_max']} |")
            if m["welded"] is not None:
                s = mesh_stats(m["welded"]["Vp"], m["welded"]["F"])
                print_(f"| MC {MC_GRIDS[i - 1]}^3 projected, welded | {i}w | {s['nv']} | {s['nf']} | {s['h']:.4f} | {s['min_angle']:.2f} | {s['max_angle']:.2f} | {s['val_min']}-{s['val_max']} |")
        print_("\nMarching-cubes input position error (distance of raw vertices to the torus; cf. Table 3.2):\n")
        print_("| grid | #V | h (raw) | removed degenerate faces | removed unreferenced verts | faces geomfit calls zero-area | L2 | Linf | rate L2 | rate Linf | area-weighted normals L2 / Linf |")
        print_("|---|---|---|---|---|---|---|---|---|---|---|")
        prev = None
        for m in mc:
            inf, h = m["info"], m["stats_raw"]["h"]
            if prev is None:
                r2 = ri = "-"
            else:
                lh = math.log(prev[0] / h)
                r2 = f"{math.log(prev[1] / inf['pos_L2']) / lh:.2f}"
                ri = f"{math.log(prev[2] / inf['pos_Linf']) / lh:.2f}"
            print_(f"| {inf['grid']}^3 | {len(m['V'])} | {h:.4f} | {inf['degenerate_removed']} | {inf['unreferenced_removed']} | {inf['geomfit_reject']} | "
                   f"{inf['pos_L2']:.2e} | {inf['pos_Linf']:.2e} | {r2} | {ri} | {inf['awn_L2']:.2e} / {inf['awn_Linf']:.2e} |")
            prev = (h, inf["pos_L2"], inf["pos_Linf"])

    if "a" in fams:
        study("(a) gmsh, vertices projected onto the torus, default settings",
              [m["exact"] for m in gm], [m["V"] for m in gm], [m["stats"]["h"] for m in gm],
              geomfit, range(1, 7), [], args.threads, args.outdir, print_)
    if "b1" in fams:
        study("(b1) marching cubes, vertices projected onto the torus, default settings",
              [m["exact"] for m in mc], [m["Vp"] for m in mc], [m["stats"]["h"] for m in mc],
              geomfit, range(1, 7), [], args.threads, args.outdir, print_,
              [None if m["welded"] is None else (m["welded"]["exact"], m["welded"]["Vp"], m["welded"]["h_proj"]) for m in mc])
    if "b2" in fams:
        for label, extra_fn in (("--noise on", lambda d: ["--noise", "on"]),
                                ("--approximate, rings d/2+1", lambda d: ["--approximate", "--rings", str(d // 2 + 1)]),
                                ("default settings", lambda d: [])):
            study(f"(b2) raw marching-cubes vertices, {label}",
                  [m["raw"] for m in mc], [m["V"] for m in mc], [m["stats_raw"]["h"] for m in mc],
                  geomfit, range(1, 5), extra_fn, args.threads, args.outdir, print_,
                  [None if m["welded"] is None else (m["welded"]["raw"], m["welded"]["V"], m["welded"]["h_raw"]) for m in mc])

    print_(f"\nTotal time {time.time() - t_start:.1f} s")
    if FAILURES:
        print_("\n## geomfit FAILURES\n")
        groups = {}
        for cmd, rc, msg in FAILURES:
            groups.setdefault((rc, msg), []).append(cmd)
        for (rc, msg), cmds in groups.items():
            print_(f"- {len(cmds)} run(s) exited {rc} with `{msg}`, e.g. `{cmds[0]}`")
    if args.report:
        with open(args.report, "w") as f:
            f.write("\n".join(lines) + "\n")
    return 1 if FAILURES else 0


if __name__ == "__main__":
    sys.exit(main())
