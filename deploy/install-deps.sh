#!/usr/bin/env bash
# Installs what deploy/ and its tests use on a Debian 12 host (idempotent): podman,
# buildah and runc (images and the smoke test), podman-compose (deploy/compose.yaml),
# debootstrap (the base image), nginx
# (the cache-affine router test) and Node.js + npm with the Kubernetes and Compose schema
# packages in deploy/k8s/validate/node_modules (offline manifest validation; npm ci from
# its package-lock.json, node_modules not committed).
# scripts/test.sh runs it; GEOMFIT_NO_DEPLOY_DEPS=1 skips it.
set -euo pipefail
cd "$(dirname "$0")/.."
# Node.js: Debian's nodejs and npm, unless a node with its own npm is installed already
# (NodeSource's nodejs ships npm and conflicts with Debian's npm package).
node_pkgs=()
command -v node >/dev/null || node_pkgs+=(nodejs)
command -v npm >/dev/null || node_pkgs+=(npm)
bash scripts/install-deps.sh podman buildah runc debootstrap uidmap slirp4netns fuse-overlayfs \
  containernetworking-plugins iptables podman-compose nginx ${node_pkgs[@]+"${node_pkgs[@]}"}
# nginx's Debian package starts a default site on port 80 where systemd runs it; the
# router test runs its own nginx on loopback ports and needs none.
if [ ! -d deploy/k8s/validate/node_modules/kubernetes-models ] ||
   [ deploy/k8s/validate/package-lock.json -nt deploy/k8s/validate/node_modules/.package-lock.json ]; then
  echo "deploy/install-deps: npm ci in deploy/k8s/validate"
  (cd deploy/k8s/validate && npm ci --no-audit --no-fund --loglevel=error)
fi
