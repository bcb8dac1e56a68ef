#!/usr/bin/env bash
# Installs every system package geomfit needs (Debian 12), plus any extra packages
# named as arguments. Idempotent; safe to re-run.
#   --server-only  only what building geomfit-server and the geomfit CLI needs
#                  (cmake -DGEOMFIT_SERVER_ONLY=ON; the container image's build stage)
set -euo pipefail
server_only=0
if [ "${1:-}" = "--server-only" ]; then server_only=1; shift; fi
pkgs=(
  build-essential cmake ninja-build pkg-config git
  libeigen3-dev libabsl-dev libspdlog-dev libfmt-dev
  libgrpc++-dev libprotobuf-dev protobuf-compiler protobuf-compiler-grpc
  libsqlite3-dev prometheus-cpp-dev libsuitesparse-dev zlib1g-dev
  # OpenBLAS (single-threaded) as the system BLAS: UMFPACK's frontal matrices run ~3x
  # faster than on the reference BLAS (bench/README.md, "Membranes").
  libopenblas0-serial
  libmimalloc-dev
)
if ((!server_only)); then
  pkgs+=(
    libgtest-dev libgmock-dev libbenchmark-dev libcgal-dev libgmp-dev libmpfr-dev
    python3 python3-grpcio python3-protobuf python3-numpy python3-scipy python3-pytest
    python3-vtk9 python3-meshio python3-tqdm
    python3-dev pybind11-dev python3-setuptools python3-pip python3-venv python3-wheel
    openssl
  )
fi
pkgs+=("$@")
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  echo "install-deps: installing ${missing[*]}"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi
