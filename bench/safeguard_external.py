#!/usr/bin/python3
"""The oscillation safeguard (4.1.3) on external torus meshes (issue 16 item 2).

Makes the meshes of bench/external_meshes.py (gmsh OpenCASCADE tori, h = 0.2,
0.16, 0.12, 0.1, 0.08, 0.04, 0.02; marching-cubes tori on N^3 grids, N = 24, 32,
40, 48, 64, 128, vertices projected onto the torus) plus two jittered structured
parametric tori (32 x 32 and 24 x 48 cells: long cells along the ring), runs
build/bench/safeguard_study on them (WALF and CMF, degrees 2-6, safeguard off and
on) and prints markdown tables: max distance to the torus and max normal error
at 3 random points per face, on/off ratios, the number of vertex fits whose
degree the safeguard lowered, and WALF's area error (what `integrate` returns).

  /usr/bin/python3 bench/safeguard_external.py build/bench/safeguard_study \\
      [--outdir /tmp/geomfit-safeguard] [--tsv results.tsv] \\
      [--baseline NAME=other.tsv ...]

--tsv formats an existing safeguard_study output instead of running it;
--baseline adds the downgrade counts and on/off ratios of another build's run on
the same meshes (e.g. the text's absolute eps = 0.01 test). Needs numpy, gmsh and
python3-skimage (scripts/install-bench-deps.sh).
"""

import argparse
import os
import subprocess
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import external_meshes as em  # noqa: E402

GMSH = [("g0.2", 0.2), ("g1", 0.16), ("g0.12", 0.12), ("g0.1", 0.1), ("g2", 0.08), ("g3", 0.04), ("g4", 0.02)]
MC = [24, 32, 40, 48, 64, 128]


def structured_torus(path, nu, nv, jitter=0.25, seed=1):
    rng = np.random.default_rng(seed)
    i, j = np.meshgrid(np.arange(nu), np.arange(nv), indexing="ij")
    u = 2 * np.pi * (i + jitter * (rng.random(i.shape) - 0.5)) / nu
    v = 2 * np.pi * (j + jitter * (rng.random(j.shape) - 0.5)) / nv
    V = np.column_stack([((em.R_CENTRE + em.R_TUBE * np.cos(v)) * np.cos(u)).ravel(),
                         ((em.R_CENTRE + em.R_TUBE * np.cos(v)) * np.sin(u)).ravel(),
                         (em.R_TUBE * np.sin(v)).ravel()])
    F = []
    for a in range(nu):
        for b in range(nv):
            p, q, r, s = a * nv + b, ((a + 1) % nu) * nv + b, ((a + 1) % nu) * nv + (b + 1) % nv, a * nv + (b + 1) % nv
            F += [(p, q, r), (p, r, s)] if (a + b) % 2 else [(p, q, s), (q, r, s)]
    em.write_obj(path, V, np.array(F))
    return path


def make_meshes(outdir):
    specs = []
    for k, (label, h) in enumerate(GMSH):
        specs.append(f"{label}={em.make_gmsh(outdir, 100 + k, h, lambda s: None)['exact']}")
    for n in MC:
        specs.append(f"mc{n}={em.make_mc(outdir, n, lambda s: None)['exact']}")
    specs.append("pt32x32=" + structured_torus(os.path.join(outdir, "pt32x32.obj"), 32, 32))
    specs.append("pt24x48=" + structured_torus(os.path.join(outdir, "pt24x48.obj"), 24, 48))
    return specs


def read_tsv(path):
    """safeguard_study's TSV: {(mesh, method, degree): row as a dict of its columns}."""
    rows = {}
    with open(path) as f:
        head = f.readline().rstrip("\n").split("\t")
        for line in f:
            r = dict(zip(head, line.rstrip("\n").split("\t")))
            if len(r) == len(head):
                rows[(r["mesh"], r["method"], int(r["degree"]))] = r
    return rows


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("study", nargs="?", default="build/bench/safeguard_study")
    ap.add_argument("--outdir", default="/tmp/geomfit-safeguard")
    ap.add_argument("--tsv", default=None)
    ap.add_argument("--baseline", action="append", default=[])
    args = ap.parse_args()
    if args.tsv is None:
        os.makedirs(args.outdir, exist_ok=True)
        args.tsv = os.path.join(args.outdir, "safeguard_study.tsv")
        with open(args.tsv, "w") as out:
            subprocess.run([os.path.abspath(args.study)] + make_meshes(args.outdir), stdout=out, check=True)
    rows = read_tsv(args.tsv)
    bases = [(b.rsplit("=", 1)[0], read_tsv(b.rsplit("=", 1)[1])) for b in args.baseline]
    meshes = list(dict.fromkeys(k[0] for k in rows))
    worst = 0.0
    for method in ("walf", "cmf"):
        print(f"\n{method.upper()}: distance and normal errors off / on (ratio), vertex fits lowered"
              + ("; " + ", ".join(f"{n}: ratios and fits lowered" for n, _ in bases) if bases else "")
              + (", WALF area error off / on" if method == "walf" else "") + "\n")
        hdr = "| mesh | #V | h | d | distance off / on (x) | normal off / on (x) | lowered |"
        hdr += "".join(f" {n}: distance x, normal x, lowered |" for n, _ in bases)
        if method == "walf":
            hdr += " area error off / on |"
        print(hdr)
        print("|" + "---|" * (hdr.count("|") - 1))
        for m in meshes:
            for d in range(3, 7):  # degree 2 is never lowered
                r = rows.get((m, method, d))
                if r is None:
                    continue
                dr, nr = float(r["dist_ratio"]), float(r["normal_ratio"])
                line = (f"| {m} | {r['vertices']} | {float(r['h']):.3f} | {d} | {float(r['dist_off']):.2e} / "
                        f"{float(r['dist_on']):.2e} ({dr:.2f}) | {float(r['normal_off']):.2e} / "
                        f"{float(r['normal_on']):.2e} ({nr:.2f}) | {r['downgraded']} |")
                for _, b in bases:
                    q = b.get((m, method, d))
                    line += (" - |" if q is None else
                             f" {float(q['dist_ratio']):.2f}, {float(q['normal_ratio']):.2f}, {q['downgraded']} |")
                if method == "walf":
                    line += f" {float(r['area_err_off']):.1e} / {float(r['area_err_on']):.1e} |"
                print(line)
                if not m.startswith("g0.2") and m not in ("g1", "mc24"):
                    worst = max(worst, dr, nr)
    print(f"\nWorst on/off ratio (distance or normal) above the coarsest levels (g0.2, g1, mc24): {worst:.2f}")


if __name__ == "__main__":
    main()
