#!/usr/bin/env bash
# Installs the extra Debian 12 packages used by bench/external_meshes.py:
# gmsh (unstructured torus meshes) and python3-skimage (marching cubes).
set -euo pipefail
exec bash "$(dirname "$0")/install-deps.sh" gmsh python3-skimage
