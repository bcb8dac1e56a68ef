#!/usr/bin/env bash
# The test command: installs, builds, and runs every test (C++ and Python) with CTest.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/build.sh
cd build
ctest --output-on-failure -j"$(nproc)" --timeout 900 "$@"
