#!/usr/bin/env bash
# Installs the extra Debian 12 packages used by bench/external_meshes.py:
# gmsh (unstructured torus meshes) and python3-skimage (marching cubes).
# Idempotent; safe to re-run. Run scripts/install-deps.sh first for the build.
set -euo pipefail
pkgs=(gmsh python3-numpy python3-skimage)
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  echo "install-bench-deps: installing ${missing[*]}"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
else
  echo "install-bench-deps: all of ${pkgs[*]} already installed"
fi
