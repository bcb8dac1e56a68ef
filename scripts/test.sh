#!/usr/bin/env bash
# The test command: installs, builds, and runs every test (C++, Python, deploy/) with CTest.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/build.sh
# podman, nginx, Node.js packages for the deploy/ tests (GEOMFIT_NO_DEPLOY_DEPS=1 skips;
# those tests then report themselves skipped). The smoke test needs the base image:
# GEOMFIT_BUILD_IMAGE=1 makes it (and the image) first, else `bash deploy/build-image.sh` once.
[ "${GEOMFIT_NO_DEPLOY_DEPS:-0}" = 1 ] || bash deploy/install-deps.sh
[ "${GEOMFIT_BUILD_IMAGE:-0}" != 1 ] || bash deploy/build-image.sh
cd build
ctest --output-on-failure -j"$(nproc)" --timeout 900 "$@"
