# Shared by deploy/*.sh (sourced): podman settings for this kind of host and names.
# Debian 12's podman 4.3 runs as root here with a private containers.conf:
#   runtime = "runc"        crun fails on kernels with hybrid cgroups
#   default_ulimits          podman's defaults exceed the hard limits of many hosts
#   cgroup_manager = "cgroupfs"  no systemd inside CI containers
# Docker users need none of this (see deploy/README.md).

GEOMFIT_IMAGE=${GEOMFIT_IMAGE:-localhost/geomfit:latest}
GEOMFIT_BASE_IMAGE=${GEOMFIT_BASE_IMAGE:-localhost/geomfit-base:bookworm}
GEOMFIT_DEPLOY_STATE=${GEOMFIT_DEPLOY_STATE:-/var/tmp/geomfit-deploy}

# Writes the private containers.conf and exports CONTAINERS_CONF (unless the caller
# set CONTAINERS_CONF to a file of their own).
geomfit_podman_env() {
  if [ -z "${CONTAINERS_CONF:-}" ]; then
    mkdir -p "$GEOMFIT_DEPLOY_STATE"
    export CONTAINERS_CONF=$GEOMFIT_DEPLOY_STATE/containers.conf
    cat >"$CONTAINERS_CONF" <<'CONF'
[containers]
default_ulimits = ["nofile=1024:1024", "nproc=4096:4096"]
[engine]
runtime = "runc"
cgroup_manager = "cgroupfs"
events_logger = "file"
CONF
  fi
}

# Prints why podman cannot run containers here and returns 1, or returns 0.
# Runs a trivial container from the base image (which must exist).
geomfit_podman_usable() {
  command -v podman >/dev/null || { echo "podman is not installed"; return 1; }
  [ "$(id -u)" -eq 0 ] || { echo "not root (these scripts run rootful podman)"; return 1; }
  podman image exists "$GEOMFIT_BASE_IMAGE" ||
    { echo "base image $GEOMFIT_BASE_IMAGE missing (deploy/build-image.sh makes it)"; return 1; }
  local out
  if ! out=$(podman run --rm --network none "$GEOMFIT_BASE_IMAGE" true 2>&1); then
    echo "podman cannot run a container on this machine: $(echo "$out" | tail -n 2 | tr '\n' ' ')"
    return 1
  fi
}
