#!/usr/bin/env bash
# The main job: installs and builds geomfit, starts geomfit-server with its embedded
# durable store, uploads the bundled torus with the geomfit CLI, computes normals and
# curvatures (degree 4) over gRPC, prints their error against the exact torus, and writes out/torus_curvature.vtp (open it in ParaView); then
# refines the torus onto its high-order surface (out/torus_refined.vtp) and integrates.
# Set GEOMFIT_KEEP_SERVER=1 to leave the server running afterwards.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/build.sh
mkdir -p out
geomfit=build/clients/cpp/geomfit
server=build/server/geomfit-server
mesh=data/torus.obj

if [ -x "$server" ]; then
  port=$(/usr/bin/python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
  target=127.0.0.1:$port
  "$server" --port "$port" --store sqlite --data-dir out/geomfit-data >out/server.log 2>&1 &
  pid=$!
  [ "${GEOMFIT_KEEP_SERVER:-0}" = 1 ] || trap 'kill -TERM $pid 2>/dev/null; wait $pid 2>/dev/null || true' EXIT
  for _ in $(seq 100); do
    "$geomfit" list --server "$target" >/dev/null 2>&1 && break
    kill -0 $pid 2>/dev/null || { cat out/server.log; exit 1; }
    sleep 0.1
  done
  echo "== geomfit-server on $target (log: out/server.log, store: out/geomfit-data)"
  "$geomfit" upload --server "$target" "$mesh"
  "$geomfit" curvature --server "$target" "$mesh" --degree 4 --output out/torus_curvature.vtp --verbose
  "$geomfit" curvature --server "$target" "$mesh" --degree 4 --output out/torus_curvature.tsv
  "$geomfit" list --server "$target"
else
  echo "== geomfit-server not built: computing in-process"
  "$geomfit" curvature --local "$mesh" --degree 4 --output out/torus_curvature.vtp --verbose
  "$geomfit" curvature --local "$mesh" --degree 4 --output out/torus_curvature.tsv
fi
echo "== wrote out/torus_curvature.vtp (and .tsv)"
bash scripts/torus_error.sh "$mesh" out/torus_curvature.tsv
"$geomfit" refine "$mesh" --factor 2 --degree 4 --output out/torus_refined.vtp
echo "== wrote out/torus_refined.vtp"
echo "== high-order integrals of the torus (exact area 11.843525, volume 1.776529):"
"$geomfit" integrate "$mesh" --degree 4
if [ "${GEOMFIT_KEEP_SERVER:-0}" = 1 ] && [ -n "${pid:-}" ]; then
  echo "== server still running (pid $pid) on $target"
fi
