#!/usr/bin/env bash
# A new user's Python install: a fresh virtual environment (system site packages: Debian's
# grpcio, protobuf, numpy), `pip install --no-build-isolation --no-index ./clients/python`,
# then README.md's Python example against a real server, once with the native transport
# (built from the configured CMake build BUILD_DIR) and once without (GEOMFIT_NATIVE=0).
# Usage: venv_install_test.sh SOURCE_DIR BUILD_DIR GEOMFIT_SERVER
set -euo pipefail
src=$1 build=$2 server_bin=$3
tmp=$(mktemp -d /tmp/geomfit_venv.XXXXXX)
server_pid=""
cleanup() { [ -n "$server_pid" ] && kill "$server_pid" 2>/dev/null; wait 2>/dev/null || true; rm -rf "$tmp"; }
trap cleanup EXIT

"$server_bin" --host=127.0.0.1 --port=0 --log-level=warn --workers=2 --store=memory > "$tmp/server.out" 2>/dev/null &
server_pid=$!
for _ in $(seq 100); do grep -q "listening on port" "$tmp/server.out" 2>/dev/null && break; sleep 0.1; done
port=$(sed -n 's/.*listening on port \([0-9]*\).*/\1/p' "$tmp/server.out" | head -1)
[ -n "$port" ] || { echo "server did not start"; exit 1; }

# The README's example (the first ```python block using upload_file), on this server.
/usr/bin/python3 - "$src/README.md" "127.0.0.1:$port" > "$tmp/example.py" <<'PY'
import re, sys
blocks = re.findall(r"```python\n(.*?)```", open(sys.argv[1]).read(), re.S)
example = next(b for b in blocks if "upload_file" in b)
print(example.replace("127.0.0.1:50051", sys.argv[2]))
PY

/usr/bin/python3 -m venv --system-site-packages "$tmp/venv"
for native in 1 0; do  # the second install replaces the first in the same venv
  rm -rf "$tmp/src"
  # A copy of the sources, as a user's checkout: the install writes nothing into ours.
  mkdir -p "$tmp/src/clients" && cp -r "$src/clients/python" "$tmp/src/clients/" && cp -r "$src/proto" "$tmp/src/"
  rm -rf "$tmp/src/clients/python/geomfit/_gen" "$tmp/src/clients/python/geomfit/"_native*.so \
         "$tmp/src/clients/python/build" "$tmp/src/clients/python/"*.egg-info
  GEOMFIT_NATIVE=$native GEOMFIT_CMAKE_BUILD_DIR=$build GEOMFIT_PROTO_DIR=$tmp/src/proto \
    "$tmp/venv/bin/pip" install -q --no-build-isolation --no-index --force-reinstall --no-deps "$tmp/src/clients/python"
  out=$(cd "$src" && env -u PYTHONPATH "$tmp/venv/bin/python" "$tmp/example.py")
  echo "$out"
  where=$(cd / && env -u PYTHONPATH "$tmp/venv/bin/python" -c "import geomfit; print(geomfit.__file__)")
  case "$where" in "$tmp/venv/"*) ;; *) echo "geomfit imported from $where, not the venv"; exit 1 ;; esac
  want=$([ "$native" = 1 ] && echo native || echo grpcio)
  echo "$out" | grep -q "^0\.[0-9.]* $want " || { echo "expected transport $want"; exit 1; }
  echo "$out" | grep -q "^Differentials(mesh_id=" || { echo "no Differentials summary"; exit 1; }
done
echo "venv install: OK"
