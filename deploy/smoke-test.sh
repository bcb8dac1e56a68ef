#!/usr/bin/env bash
# Smoke test of the geomfit image (podman, root): a container on loopback ports with a
# fresh data volume, read-only root filesystem and no capabilities; health SERVING (and the image's HEALTHCHECK); upload of
# data/torus.obj with the host's geomfit CLI; curvature bit-identical to
# `geomfit curvature --local`; /metrics scraped; runs as UID 10001; stop (SIGTERM
# drain) exits 0; started again, the mesh is still there. Removes what it created.
#
#   bash deploy/smoke-test.sh [--build] [GEOMFIT_CLI]   (default build/clients/cpp/geomfit)
#
# Without a host CLI (nothing built on the host), the image's own geomfit runs in a
# second container on the host network instead.
# --build first runs deploy/build-image.sh (incremental: cached layers and ccache).
# Exit status 77 (CTest's SKIP_RETURN_CODE) when podman cannot run containers here
# or the image is missing; the reason is printed.
set -euo pipefail
cd "$(dirname "$0")/.."
. deploy/lib.sh
build=0
if [ "${1:-}" = "--build" ]; then build=1; shift; fi
cli=$(readlink -f "${1:-build/clients/cpp/geomfit}")
skip() { echo "SKIPPED deploy smoke test: $*"; exit 77; }
say() { echo "== smoke: $*"; }

geomfit_podman_env
why=$(geomfit_podman_usable) || skip "$why"
if ((build)); then
  bash deploy/build-image.sh >"$GEOMFIT_DEPLOY_STATE/build-image.log" 2>&1 ||
    { tail -n 30 "$GEOMFIT_DEPLOY_STATE/build-image.log"; echo "smoke: image build failed" >&2; exit 1; }
  tail -n 3 "$GEOMFIT_DEPLOY_STATE/build-image.log"
fi
podman image exists "$GEOMFIT_IMAGE" || skip "image $GEOMFIT_IMAGE missing (bash deploy/build-image.sh)"

# podman without systemd reports on stderr that it cannot schedule the periodic
# HEALTHCHECK timer; the check itself is run below with `podman healthcheck run`.
pm() { podman "$@" 2> >(grep -v 'unable to get systemd connection' >&2); }

free_port() { python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])'; }
port=$(free_port)
mport=$(free_port)
name=geomfit-smoke-$$
volume=geomfit-smoke-$$
work=$(mktemp -d)
# G: the geomfit CLI; $mesh and $out: the torus and the output folder as it sees them.
if [ -x "$cli" ]; then
  G() { "$cli" "$@"; }
  mesh=data/torus.obj out=$work
else
  say "no host CLI at $cli: using the image's geomfit"
  chmod 777 "$work"
  G() { podman run --rm --no-healthcheck --network host --entrypoint geomfit -v "$PWD/data:/mesh:ro" -v "$work:/out" \
          "$GEOMFIT_IMAGE" "$@"; }
  mesh=/mesh/torus.obj out=/out
fi
cleanup() {
  podman rm -f -t 0 "$name" >/dev/null 2>&1 || true
  podman volume rm -f "$volume" >/dev/null 2>&1 || true
  rm -rf "$work"
}
trap cleanup EXIT
target=127.0.0.1:$port

wait_serving() {
  for _ in $(seq 150); do
    G health --server "$target" --timeout 1 >/dev/null 2>&1 && return 0
    [ "$(podman inspect --format '{{.State.Running}}' "$name")" = true ] || break
    sleep 0.2
  done
  podman logs "$name" | tail -n 20
  echo "smoke: the server did not become SERVING" >&2
  return 1
}

say "image $GEOMFIT_IMAGE ($(podman image inspect --format '{{.Size}}' "$GEOMFIT_IMAGE" | awk '{printf "%.0f MB", $1 / 1e6}')), gRPC $target, metrics 127.0.0.1:$mport"
podman volume create "$volume" >/dev/null
# As compose.yaml and the Kubernetes manifests run it: read-only root filesystem, no
# capabilities, no privilege escalation.
pm run -d --name "$name" -p "127.0.0.1:$port:50051" -p "127.0.0.1:$mport:9464" \
  --read-only --tmpfs /tmp --cap-drop=ALL --security-opt=no-new-privileges \
  -v "$volume:/data" "$GEOMFIT_IMAGE" --drain-seconds=5 --log-format=json >/dev/null
wait_serving
[ "$(podman exec "$name" id -u)" = 10001 ] || { echo "smoke: not running as UID 10001" >&2; exit 1; }
podman healthcheck run "$name" || { echo "smoke: the image's HEALTHCHECK failed" >&2; exit 1; }
say "SERVING; runs as UID 10001; HEALTHCHECK healthy"

id=$(G upload --server "$target" "$mesh" | awk 'NR == 2 {print $1}')
[ -n "$id" ] || { echo "smoke: upload printed no mesh id" >&2; exit 1; }
G curvature --server "$target" "$id" --degree 3 --output "$out/remote.npy"
G curvature --server "$target" "$id" --degree 3 --output "$out/remote.tsv"
G curvature --local "$mesh" --degree 3 --output "$out/local.npy"
G curvature --local "$mesh" --degree 3 --output "$out/local.tsv"
cmp "$work/local.npy" "$work/remote.npy" && cmp "$work/local.tsv" "$work/remote.tsv" ||
  { echo "smoke: curvature in the container differs from --local" >&2; exit 1; }
say "uploaded $id; curvature bit-identical to --local ($(($(wc -l <"$work/local.tsv") - 1)) vertices)"

python3 - "$mport" <<'PY'
import sys, urllib.request
body = urllib.request.urlopen("http://127.0.0.1:%s/metrics" % sys.argv[1], timeout=10).read().decode()
want = ['geomfit_requests_total{method="UploadMesh",code="OK"} 1',
        'geomfit_requests_total{method="ComputeDifferentials",code="OK"} 2',
        'geomfit_store_meshes 1', 'geomfit_build_info{version="', 'process_resident_memory_bytes ',
        'process_open_fds ', 'process_start_time_seconds ']
missing = [w for w in want if w not in body]
if missing:
    sys.exit("smoke: /metrics lacks %s" % missing)
PY
say "/metrics scraped"

pm stop -t 30 "$name" >/dev/null
code=$(podman inspect --format '{{.State.ExitCode}}' "$name")
[ "$code" = 0 ] || { podman logs "$name" | tail -n 20; echo "smoke: exit status $code after SIGTERM" >&2; exit 1; }
podman logs "$name" 2>&1 | grep -q '"message":"exit"' || { echo "smoke: no JSON 'exit' log line" >&2; exit 1; }
say "stopped: drained, exit status 0"

pm start "$name" >/dev/null
wait_serving
G info --server "$target" "$id" | grep -q "^$id" || { echo "smoke: mesh $id lost on restart" >&2; exit 1; }
G curvature --server "$target" "$id" --degree 3 --output "$out/again.npy"
cmp "$work/local.npy" "$work/again.npy" || { echo "smoke: curvature differs after restart" >&2; exit 1; }
say "restarted: mesh $id still stored, curvature unchanged"
pm stop -t 30 "$name" >/dev/null
echo "deploy smoke test: 1 passed, 0 failed"
