#!/usr/bin/env bash
# The C++ package as a downstream project meets it: install the build into a temporary
# prefix, configure and build tests/install/consumer against it with find_package(geomfit)
# and run it. Usage: install_test.sh BUILD_DIR SOURCE_DIR
set -euo pipefail
build=$1 src=$2
tmp=$(mktemp -d /tmp/geomfit_install.XXXXXX)
trap 'rm -rf "$tmp"' EXIT
cmake --install "$build" --prefix "$tmp/prefix" > /dev/null
test -x "$tmp/prefix/bin/geomfit" && test -x "$tmp/prefix/bin/geomfit-server"
test -f "$tmp/prefix/lib/cmake/geomfit/geomfitConfig.cmake"
launcher=()
command -v ccache > /dev/null && launcher=(-DCMAKE_CXX_COMPILER_LAUNCHER=ccache)
cmake -S "$src/tests/install/consumer" -B "$tmp/consumer" -G Ninja -DCMAKE_BUILD_TYPE=Release \
      -DCMAKE_PREFIX_PATH="$tmp/prefix" "${launcher[@]}" > /dev/null
cmake --build "$tmp/consumer" > /dev/null
out=$("$tmp/consumer/consumer")
echo "$out"
case "$out" in *"server $tmp/prefix/bin/geomfit-server"*) ;; *) echo "geomfit::server not imported"; exit 1 ;; esac
# The installed programs run without the build tree.
"$tmp/prefix/bin/geomfit" generate torus --level 8 --output "$tmp/t.obj"
"$tmp/prefix/bin/geomfit" curvature --local "$tmp/t.obj" --degree 4 --output "$tmp/t.npy"
test -s "$tmp/t.npy"
echo "install: OK"
