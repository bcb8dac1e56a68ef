#!/usr/bin/env bash
# Prints the error of a curvature TSV (geomfit curvature --output F.tsv) of the bundled
# torus (R = 1, r = 0.3, vertices on the surface) against the exact torus: max and RMS
# relative error of H, and max error of K and of the normals.
# Usage: torus_error.sh MESH.obj CURVATURE.tsv
set -euo pipefail
/usr/bin/python3 - "$1" "$2" <<'PY'
import sys
import numpy as np
R, r = 1.0, 0.3
p = np.array([l.split()[1:4] for l in open(sys.argv[1]) if l.startswith("v ")], dtype=float)
t = np.loadtxt(sys.argv[2], ndmin=2)  # the header line starts with '#'
rho = np.hypot(p[:, 0], p[:, 1])
cos_v = (rho - R) / r
H = (R + 2 * r * cos_v) / (2 * r * (R + r * cos_v))          # outward normals, H = +1/R on spheres
K = cos_v / (r * (R + r * cos_v))
n = np.stack([cos_v * p[:, 0] / rho, cos_v * p[:, 1] / rho, p[:, 2] / r], axis=1)
eH = np.abs(t[:, 3] - H) / np.abs(H).max()
print("== error against the exact torus (degree %d, %d vertices): H max %.2e, rms %.2e (relative to max |H|); "
      "K max %.2e; normals max %.2e" % (int(np.median(t[:, 13])), len(p), eH.max(), np.sqrt((eH ** 2).mean()),
                                        np.abs(t[:, 4] - K).max(), np.linalg.norm(t[:, 0:3] - n, axis=1).max()))
PY
