#!/usr/bin/env bash
# Builds the geomfit OCI image with podman (rootful), from a Debian 12 base made with
# debootstrap when it is missing (no registry needs to be reachable):
#
#   bash deploy/build-image.sh            # -> localhost/geomfit:latest and :VERSION
#
# Environment: GEOMFIT_IMAGE (tag, default localhost/geomfit:latest),
# GEOMFIT_BASE_IMAGE (default localhost/geomfit-base:bookworm), DEBIAN_MIRROR.
#
# With docker and a registry instead (no base image to make):
#   docker build -f deploy/Containerfile --build-arg BASE=debian:bookworm \
#     --build-arg REVISION=$(git rev-parse --short=12 HEAD) -t geomfit:latest .
# (docker keeps the HEALTHCHECK; the smoke test is podman-only.)
set -euo pipefail
cd "$(dirname "$0")/.."
. deploy/lib.sh
geomfit_podman_env

if ! podman image exists "$GEOMFIT_BASE_IMAGE"; then
  echo "== base image $GEOMFIT_BASE_IMAGE: debootstrap --variant=minbase bookworm (a few minutes)"
  root=$(mktemp -d "${TMPDIR:-/var/tmp}/geomfit-rootfs.XXXXXX")
  trap 'rm -rf "$root"' EXIT
  debootstrap --variant=minbase bookworm "$root" "${DEBIAN_MIRROR:-http://deb.debian.org/debian}" >"$root.log" 2>&1 ||
    { tail -n 20 "$root.log"; exit 1; }
  rm -f "$root.log"
  # The Debian security archive too, as in debian:bookworm images.
  echo "deb http://deb.debian.org/debian-security bookworm-security main" >>"$root/etc/apt/sources.list"
  rm -rf "$root"/var/cache/apt/archives/*.deb "$root"/var/lib/apt/lists/*
  tar -C "$root" -c . | podman import --change 'CMD ["/bin/bash"]' - "$GEOMFIT_BASE_IMAGE" >/dev/null
  rm -rf "$root"
  trap - EXIT
fi

version=$(sed -n 's/^project(geomfit VERSION \([0-9.]*\).*/\1/p' CMakeLists.txt)
revision=$(git rev-parse --short=12 HEAD 2>/dev/null || true)
source=$(git remote get-url origin 2>/dev/null || true)
echo "== building $GEOMFIT_IMAGE (geomfit $version${revision:+, git $revision})"
# --format docker keeps the HEALTHCHECK (the OCI image config has no field for it).
podman build -f deploy/Containerfile --format docker --build-arg BASE="$GEOMFIT_BASE_IMAGE" \
  --build-arg VERSION="$version" --build-arg REVISION="$revision" --build-arg SOURCE="$source" \
  --layers -t "$GEOMFIT_IMAGE" -t "${GEOMFIT_IMAGE%:*}:$version" .
podman image ls --format '{{.Repository}}:{{.Tag}} {{.Size}}' | grep -E "^(${GEOMFIT_IMAGE%:*}|${GEOMFIT_BASE_IMAGE%:*}):" || true
