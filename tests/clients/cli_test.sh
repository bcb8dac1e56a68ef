#!/usr/bin/env bash
# End-to-end test of the geomfit command-line tool in local mode.
# Usage: cli_test.sh PATH/TO/geomfit
set -u
[ $# -eq 1 ] || { echo "usage: $0 PATH/TO/geomfit" >&2; exit 2; }
G="$(realpath "$1")"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
cd "$work" || exit 1

checks=0
fail() { echo "FAIL: $*" >&2; exit 1; }
pass() { checks=$((checks + 1)); }

# Runs geomfit and fails the test unless it exits 0.
run_ok() {
  "$G" "$@" >stdout.txt 2>stderr.txt || fail "geomfit $* exited $?: $(cat stderr.txt)"
  pass
}

# expect_error RC PATTERN ARGS...: exit code RC, exactly one stderr line
# "geomfit: error: ..." containing PATTERN, nothing on stdout.
expect_error() {
  local want_rc="$1" pattern="$2"
  shift 2
  "$G" "$@" >stdout.txt 2>stderr.txt
  local rc=$?
  [ "$rc" -eq "$want_rc" ] || fail "geomfit $*: exit $rc, expected $want_rc ($(cat stderr.txt))"
  [ "$(wc -l <stderr.txt)" -eq 1 ] || fail "geomfit $*: stderr is not one line: $(cat stderr.txt)"
  grep -q '^geomfit: error: ' stderr.txt || fail "geomfit $*: bad error line: $(cat stderr.txt)"
  grep -q -- "$pattern" stderr.txt || fail "geomfit $*: error lacks '$pattern': $(cat stderr.txt)"
  [ ! -s stdout.txt ] || fail "geomfit $*: wrote to stdout on error"
  pass
}

header=$'# nx\tny\tnz\tH\tK\tk1\tk2\te1x\te1y\te1z\te2x\te2y\te2z\tdegree_used\tpoints\tflags'

# --- generate, curvature to TSV -------------------------------------------------
run_ok generate torus --level 8 --output t.obj
nv=$(grep -c '^v ' t.obj)
[ "$nv" -gt 0 ] || fail "generated mesh has no vertices"

run_ok curvature --local t.obj --degree 2 --output out.tsv
[ "$(head -n 1 out.tsv)" = "$header" ] || fail "bad TSV header: $(head -n 1 out.tsv)"
[ "$(wc -l <out.tsv)" -eq $((nv + 1)) ] || fail "out.tsv has $(wc -l <out.tsv) lines, want $((nv + 1))"
awk -F'\t' 'NF != 16 { exit 1 }' out.tsv || fail "a TSV line does not have 16 fields"
# Degree 2 everywhere on a fine closed torus, mean curvature positive on the outer rim.
awk -F'\t' 'NR > 1 && $14 != 2 { exit 1 }' out.tsv || fail "degree_used is not 2 everywhere"
pass

# Without --output: the same TSV on stdout.
run_ok curvature --local t.obj --degree 2
cmp -s stdout.txt out.tsv || fail "stdout TSV differs from out.tsv"

# Normal refinement: a degree-3 pre-fit's normals at degree 2 (other normals, degree 2
# still reported); a pre-fit below the degree is a usage error naming the option.
run_ok curvature --local t.obj --degree 2 --normal-degree 3 --output nd.tsv
[ "$(wc -l <nd.tsv)" -eq $((nv + 1)) ] || fail "nd.tsv has $(wc -l <nd.tsv) lines"
awk -F'\t' 'NR > 1 && $14 != 2 { exit 1 }' nd.tsv || fail "--normal-degree 3: degree_used is not 2"
paste out.tsv nd.tsv | awk -F'\t' 'NR > 1 && $1 != $17 { d++ } END { exit !(d > 0) }' ||
  fail "--normal-degree 3 left every normal unchanged"
pass
expect_error 2 "normal_degree" curvature --local t.obj --degree 2 --normal-degree 1
# Slope refinement: degree 2's normals refined from the neighbours' (other normals,
# degree 2 still reported); more than 3 passes is a usage error naming the option.
run_ok curvature --local t.obj --degree 2 --slope-refinement 1 --output sr.tsv
[ "$(wc -l <sr.tsv)" -eq $((nv + 1)) ] || fail "sr.tsv has $(wc -l <sr.tsv) lines"
awk -F'\t' 'NR > 1 && $14 != 2 { exit 1 }' sr.tsv || fail "--slope-refinement 1: degree_used is not 2"
paste out.tsv sr.tsv | awk -F'\t' 'NR > 1 && $1 != $17 { d++ } END { exit !(d > 0) }' ||
  fail "--slope-refinement 1 left every normal unchanged"
pass
expect_error 2 "slope_refinement" curvature --local t.obj --degree 2 --slope-refinement 4
# Degree 2's refinement by the fit's own operator (off by default): --quadratic-hermite
# changes the degree-2 normals and mean curvatures (degree 2 still reported).
run_ok curvature --local t.obj --degree 2 --quadratic-hermite --output qh.tsv
[ "$(wc -l <qh.tsv)" -eq $((nv + 1)) ] || fail "qh.tsv has $(wc -l <qh.tsv) lines"
awk -F'\t' 'NR > 1 && $14 != 2 { exit 1 }' qh.tsv || fail "--quadratic-hermite: degree_used is not 2"
paste out.tsv qh.tsv | awk -F'\t' 'NR > 1 && ($1 != $17 || $2 != $18 || $3 != $19) { d++ } END { exit !(d > 0) }' ||
  fail "--quadratic-hermite left every degree-2 normal unchanged"
paste out.tsv qh.tsv | awk -F'\t' 'NR > 1 && $4 != $20 { d++ } END { exit !(d > 0) }' ||
  fail "--quadratic-hermite left every degree-2 mean curvature unchanged"
pass
# Degree 3's slope refinement and Hermite curvatures (on by default): --plain-cubic keeps
# the plain fit's normals and Hessian, so other normals and mean curvatures.
run_ok curvature --local t.obj --degree 3 --output c3.tsv
run_ok curvature --local t.obj --degree 3 --plain-cubic --output p3.tsv
paste c3.tsv p3.tsv | awk -F'\t' 'NR > 1 && ($1 != $17 || $2 != $18 || $3 != $19) { d++ } END { exit !(d > 0) }' ||
  fail "--plain-cubic left every degree-3 normal unchanged"
paste c3.tsv p3.tsv | awk -F'\t' 'NR > 1 && $4 != $20 { d++ } END { exit !(d > 0) }' ||
  fail "--plain-cubic left every degree-3 mean curvature unchanged"
pass
# Degree 1's Hermite normals (on by default): --plain-plane keeps the plain plane fit's normals.
run_ok curvature --local t.obj --degree 1 --output c1.tsv
run_ok curvature --local t.obj --degree 1 --plain-plane --output p1.tsv
paste c1.tsv p1.tsv | awk -F'\t' 'NR > 1 && ($1 != $17 || $2 != $18 || $3 != $19) { d++ } END { exit !(d > 0) }' ||
  fail "--plain-plane left every degree-1 normal unchanged"
pass
# Degrees 4-5's Hermite jets (on by default at degree 5, opt-in at degree 4): --hermite-jets
# changes the degree-4 mean curvatures; --plain-jets those of degree 5.
run_ok curvature --local t.obj --degree 4 --output c4.tsv
run_ok curvature --local t.obj --degree 4 --hermite-jets --output j4.tsv
paste c4.tsv j4.tsv | awk -F'\t' 'NR > 1 && $4 != $20 { d++ } END { exit !(d > 0) }' ||
  fail "--hermite-jets left every degree-4 mean curvature unchanged"
run_ok curvature --local t.obj --degree 5 --output c5.tsv
run_ok curvature --local t.obj --degree 5 --plain-jets --output p5.tsv
paste c5.tsv p5.tsv | awk -F'\t' 'NR > 1 && $4 != $20 { d++ } END { exit !(d > 0) }' ||
  fail "--plain-jets left every degree-5 mean curvature unchanged"
expect_error 2 "exclude" curvature --local t.obj --degree 5 --hermite-jets --plain-jets
pass

# --- VTP and NPY ------------------------------------------------------------------
run_ok curvature --local t.obj --degree 3 --method lop --two-pass --output out.vtp --verbose
grep -q "read t.obj" stderr.txt || fail "--verbose printed no timings"
# Binary appended by default (VTK's reader checks it in tests/python/test_vtk_output.py).
grep -a -q '<VTKFile type="PolyData" version="1.0" byte_order="LittleEndian" header_type="UInt64">' out.vtp ||
  fail "VTP lacks the VTKFile element"
grep -a -q '<AppendedData encoding="raw">' out.vtp || fail "VTP is not binary appended"
grep -a -q "NumberOfPoints=\"$nv\"" out.vtp || fail "VTP point count is not $nv"
grep -a -q '<PointData Normals="Normals" Scalars="MeanCurvature">' out.vtp ||
  fail "VTP has no active normals and scalars"
for name in Normals MeanCurvature GaussianCurvature k1 k2 Direction1 Direction2 \
  CurvatureTensor DegreeUsed StencilPoints Flags; do
  grep -a -q "Name=\"$name\"" out.vtp || fail "VTP lacks array $name"
done
grep -a -q 'type="UInt8" Name="Flags"' out.vtp || fail "Flags is not UInt8"
! grep -a -q 'Name="Points" NumberOfComponents="1"' out.vtp || fail "a point-data array is named Points"
# --ascii: the same arrays as text.
run_ok curvature --local t.obj --degree 3 --method lop --two-pass --output ascii.vtp --ascii
/usr/bin/python3 - ascii.vtp "$nv" <<'PY' || fail "python could not read ascii.vtp"
import sys, xml.etree.ElementTree as ET
piece = ET.parse(sys.argv[1]).getroot().find("PolyData/Piece")
nv = int(sys.argv[2])
assert int(piece.get("NumberOfPoints")) == nv
types = {a.get("Name"): a.get("type") for a in piece.find("PointData")}
assert types["DegreeUsed"] == "Int32" and types["Flags"] == "UInt8", types
for a in piece.find("PointData"):
    if a.get("format") == "ascii":
        assert len(a.text.split()) == nv * int(a.get("NumberOfComponents")), a.get("Name")
PY
pass

run_ok curvature --local t.obj --approximate --output out.npy
[ "$(head -c 6 out.npy | tail -c 5)" = "NUMPY" ] || fail "out.npy lacks the NUMPY magic"
hlen=$(od -An -tu2 -j8 -N2 --endian=little out.npy | tr -d ' ')
[ "$(stat -c %s out.npy)" -eq $((10 + hlen + nv * 13 * 8)) ] || fail "out.npy has the wrong size"
head -c $((10 + hlen)) out.npy | grep -q "'shape': ($nv, 13)" || fail "out.npy header lacks the shape"
pass

# .npy rows equal the TSV's (%.17g: exact) on a mesh of 21,168 vertices, numbered
# locally (rows packed a block at a time) and shuffled (relabelled for the fit: each
# block of fits evaluated as fitted, the table in 8192-row pieces, the last partial).
run_ok generate torus --level 84 --jitter 0.2 --output big.obj
/usr/bin/python3 - big.obj big_s.obj <<'PY' || fail "could not shuffle big.obj"
import random, sys
lines = open(sys.argv[1]).read().split("\n")
vs = [l for l in lines if l.startswith("v ")]
fs = [l.split()[1:] for l in lines if l.startswith("f ")]
rng = random.Random(3)
perm = list(range(len(vs)))
rng.shuffle(perm)  # old vertex i becomes perm[i]
out = [None] * len(vs)
for i, l in enumerate(vs):
    out[perm[i]] = l
rng.shuffle(fs)
with open(sys.argv[2], "w") as f:
    f.write("\n".join(out) + "\n")
    for face in fs:
        f.write("f " + " ".join(str(perm[int(c.split("/")[0]) - 1] + 1) for c in face) + "\n")
PY
for m in big big_s; do
  run_ok curvature --local $m.obj --degree 2 --output $m.npy
  run_ok curvature --local $m.obj --degree 2 --output $m.tsv
  /usr/bin/python3 - $m.npy $m.tsv <<'PY' || fail "$m.npy differs from $m.tsv"
import math, struct, sys
raw = open(sys.argv[1], "rb").read()
hlen = struct.unpack("<H", raw[8:10])[0]
vals = struct.unpack("<%dd" % ((len(raw) - 10 - hlen) // 8), raw[10 + hlen:])
rows = [l.split("\t") for l in open(sys.argv[2]).read().splitlines() if not l.startswith("#")]
assert len(rows) == 21168 and len(vals) == 13 * len(rows), (len(rows), len(vals))
for i, r in enumerate(rows):
    for c in range(13):
        a, b = vals[13 * i + c], float(r[c])
        assert a == b or (math.isnan(a) and math.isnan(b)), (i, c, a, b)
PY
  pass
done

# --- convert: a binary PLY round trip is exact, so results are identical ---------
run_ok convert t.obj t.ply
run_ok curvature --local t.ply --degree 2 --output ply.tsv
cmp -s ply.tsv out.tsv || fail "curvature of the PLY copy differs"
run_ok convert t.ply t.off
run_ok convert t.off t.vtp
grep -a -q '<AppendedData encoding="raw">' t.vtp || fail "convert: t.vtp is not binary"
run_ok convert t.off t_ascii.vtu --ascii
grep -q 'type="UInt8" Name="types" format="ascii"' t_ascii.vtu || fail "convert --ascii: not text"

# --- help and version ------------------------------------------------------------
run_ok --help
grep -q curvature stdout.txt || fail "--help lacks the curvature command"
run_ok curvature --help
grep -q -- "--degree" stdout.txt || fail "curvature --help lacks --degree"
run_ok --version
grep -q '^geomfit ' stdout.txt || fail "--version output: $(cat stdout.txt)"

# --- bad input -----------------------------------------------------------------
printf 'v 0 0 0\nv 1 nan 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4 3\n' >nan.obj
printf 'v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 2 0\nf 1 2 3 4 5\n' >pentagon.obj
printf 'v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 7\n' >range.obj

expect_error 1 "missing.obj" curvature --local missing.obj
expect_error 1 "not finite" curvature --local nan.obj
expect_error 1 "line 6.*5 vertices" curvature --local pentagon.obj
expect_error 1 "out of range" curvature --local range.obj
# convert refuses faces naming vertices that do not exist (it used to write 0 1 998).
printf 'v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 999\n' >bad999.obj
expect_error 1 "bad999.obj: line 4: face 0: vertex index 999 is out of range" convert bad999.obj bad.ply
[ ! -e bad.ply ] || fail "convert of an invalid mesh left bad.ply"
expect_error 2 "degree" curvature --local t.obj --degree 9 --output bad.tsv
[ ! -e bad.tsv ] || fail "a failed run left bad.tsv"
expect_error 2 "not an integer" curvature --local t.obj --degree two
expect_error 2 "requires a value" curvature --local t.obj --degree
expect_error 2 "unknown option '--bogus'" curvature --local t.obj --bogus
expect_error 2 "lhf, lop, xu or lscm" curvature --local t.obj --method xyz
expect_error 2 "off, on or auto" curvature --local t.obj --noise sometimes
expect_error 2 "qr or svd" curvature --local t.obj --solver lu
run_ok curvature --local t.obj --noise auto --solver svd --output noise.tsv
expect_error 2 "unknown extension" curvature --local t.obj --output out.png
expect_error 2 "needs MESH" curvature --local
expect_error 2 "unknown command" frobnicate
expect_error 2 "missing command"
expect_error 2 "unknown surface" generate cube --output c.obj
expect_error 2 "needs --output" generate sphere --level 4
expect_error 1 "cannot write" generate sphere --level 4 --output no/such/dir/s.obj

# --- chapter 4: integrate, refine, nodes, project ------------------------------------
run_ok generate sphere --level 8 --output s.obj
run_ok integrate s.obj --degree 4
/usr/bin/python3 - stdout.txt <<'PY' || fail "sphere area/volume not within 1e-3 of 4 pi, 4 pi / 3"
import math, sys
vals = dict(line.split() for line in open(sys.argv[1]))
assert abs(float(vals["area"]) - 4 * math.pi) < 1e-3 * 4 * math.pi, vals
assert abs(float(vals["volume"]) - 4 * math.pi / 3) < 1e-3 * 4 * math.pi / 3, vals
PY
/usr/bin/python3 -c "
for line in open('s.obj'):
    if line.startswith('v '): x, y, z = map(float, line.split()[1:4]); print(x * x)
" >x2.txt
run_ok integrate s.obj --degree 4 --scalar x2.txt
/usr/bin/python3 - stdout.txt <<'PY' || fail "integral of x^2 over the unit sphere is not 4 pi / 3"
import math, sys
vals = dict(line.split() for line in open(sys.argv[1]))
assert abs(float(vals["scalar"]) - 4 * math.pi / 3) < 1e-3, vals
PY
# Sharp features in integration: a cylinder with flat caps (area 6 pi).
run_ok generate cylinder --level 8 --output cyl.obj
run_ok integrate cyl.obj --degree 3 --feature-angle 45
cp stdout.txt cyl_feature.txt
run_ok integrate cyl.obj --degree 3
/usr/bin/python3 - cyl_feature.txt stdout.txt <<'PY' || fail "feature integration not 5x better than plain WALF on the cylinder"
import math, sys
feat, plain = (dict(line.split() for line in open(f)) for f in sys.argv[1:3])
ef, ep = (abs(float(v["area"]) - 6 * math.pi) for v in (feat, plain))
assert ef < 1e-3 * 6 * math.pi and 5 * ef < ep, (ef, ep)
PY
run_ok refine s.obj --factor 2 --output s2.obj
[ "$(grep -c '^f ' s2.obj)" -eq $((4 * $(grep -c '^f ' s.obj))) ] || fail "refine did not split every face in four"
run_ok nodes s.obj --order 3 --output s3
[ "$(wc -l <s3.elements.tsv)" -eq "$(grep -c '^f ' s.obj)" ] || fail "nodes: one element line per face"
grep -q "NumberOfPolys=\"$((9 * $(grep -c '^f ' s.obj)))\"" s3.vtp || fail "nodes: s3.vtp should split each face into 9"
printf '0 0.25 0.25\n1 0.1 0.2\n' >fp.txt
run_ok project s.obj --face-points fp.txt --method cmf
[ "$(wc -l <stdout.txt)" -eq 3 ] || fail "project: header + 2 lines expected"
printf '0 0 1.05\n0.7 0.7 0.1\n' >xyz.txt
run_ok project s.obj --points xyz.txt --output proj.tsv
/usr/bin/python3 - proj.tsv <<'PY' || fail "projected points are not on the unit sphere"
import sys
rows = [l.split() for l in open(sys.argv[1]).read().splitlines()[1:]]
for r in rows:
    x, y, z = map(float, r[3:6]); assert abs((x*x + y*y + z*z) ** 0.5 - 1) < 1e-4, r
PY
printf '0 0.9 0.3\n' >outside.txt
expect_error 1 "outside triangle face 0" project s.obj --face-points outside.txt
printf '1\n2\n' >short.txt
expect_error 1 "shape 2 x 1" integrate s.obj --scalar short.txt
expect_error 2 "factor" refine s.obj --factor 1 --output r.obj
expect_error 2 "walf, cmf or linear" refine s.obj --method spline --output r.obj

# Sharp features: the refined cylinder keeps its rims and flat caps.
run_ok generate cylinder --level 6 --output cyl.obj
run_ok refine cyl.obj --factor 2 --feature-angle 45 --output cyl2.obj
/usr/bin/python3 - cyl2.obj <<'PY' || fail "refined cylinder left the cylinder"
import math, sys
worst = 0
for line in open(sys.argv[1]):
    if not line.startswith("v "): continue
    x, y, z = map(float, line.split()[1:4]); r = math.hypot(x, y)
    rim = math.hypot(r - 1, abs(z) - 1)
    side = abs(r - 1) if abs(z) <= 1 else rim
    cap = abs(abs(z) - 1) if r <= 1 else rim
    worst = max(worst, min(side, cap))
assert worst < 2e-3, worst
PY

# --- outputs to /dev/null and to stdout ('-'); '#' headers read by numpy.loadtxt
run_ok generate torus --level 24 --output p.obj
run_ok curvature p.obj --degree 2 --output /dev/null
[ ! -s stdout.txt ] || fail "--output /dev/null wrote to stdout"
[ -c /dev/null ] || fail "/dev/null was replaced"
run_ok curvature p.obj --degree 2 --output -
cmp -s stdout.txt <("$G" curvature p.obj --degree 2) || fail "--output - differs from the default stdout TSV"
/usr/bin/python3 -c "import numpy, sys; t = numpy.loadtxt(sys.argv[1], ndmin=2); assert t.shape == (1728, 16), t.shape" \
  stdout.txt || fail "numpy.loadtxt cannot read the TSV without skiprows"
run_ok generate torus --level 8 --output -
grep -q '^v ' stdout.txt || fail "generate --output - did not write OBJ to stdout"
run_ok refine p.obj --output /dev/null
run_ok convert p.obj /dev/null
run_ok project p.obj --points xyz.txt --output -
head -c 1 stdout.txt | grep -q '#' || fail "project TSV header lacks #"

# --- progress bars: forced on with --progress (stderr is a file here), off by default
run_ok curvature p.obj --degree 4 --output p.npy
[ ! -s stderr.txt ] || fail "progress drawn on a non-terminal stderr: $(cat stderr.txt)"
run_ok curvature --progress p.obj --degree 4 --output p.npy
tr '\r' '\n' <stderr.txt >progress.txt
for phase in read fit evaluate write; do
  grep -q "^$phase " progress.txt || fail "no '$phase' progress: $(cat progress.txt)"
done
grep -Eq '^evaluate +\[#{24}\] 100%  1728/1728  [0-9.e+]+/s  [0-9.]+ s' progress.txt ||
  fail "evaluate bar lacks 100%, count or rate: $(cat progress.txt)"
run_ok integrate p.obj --progress --no-progress
[ "$(grep -c . stderr.txt)" -eq 0 ] || fail "--no-progress (last) still drew"
run_ok integrate p.obj --progress
grep -q "integrate" stderr.txt || fail "no integrate progress"
run_ok nodes p.obj --order 2 --output pn --progress
tr '\r' '\n' <stderr.txt | grep -q "^write " || fail "nodes: no write progress"

echo "cli_test: $checks checks passed"
