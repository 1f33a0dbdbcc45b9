#!/usr/bin/env bash
# Build the glmav-observer image with podman and run the compose stack's three services
# (Zenoh router, simulator, observer) on the host network, loopback only; pass when the
# observer's velocity estimates and health arrive over Zenoh, in the image's own
# subscriber. Documented in docs/container.md (recipe, measured times, image size).
#
# Steps: (1) the stand-in base image (scripts/build-base-image.sh, skipped when present),
#        (2) `podman build` of ./Dockerfile against it with --pull=never,
#        (3) image checks: non-root user, entrypoint, health check, pinned versions,
#        (4) the stack, (5) the assertion on what arrives over Zenoh, (6) the health check.
#
# Usage: sudo scripts/container-check.sh [--build-only] [--keep]
#   --build-only   stop after steps 1-3
#   --keep         leave the containers running on success (they are removed on failure too,
#                  unless --keep); logs are written to $GLMAV_CHECK_DIR (default: a temp dir)
# Environment: GLMAV_IMAGE (default localhost/glmav-observer:check),
#              GLMAV_PODMAN_STORAGE (storage driver), GLMAV_CHECK_SECONDS (sim duration, 30)
#
# The package index and CA bundle the build uses are read from this host at run time (pip
# config, PIP_* environment, SSL_CERT_FILE...) and handed to the build as secrets; nothing
# about them is stored in the repository or in the image.
set -euo pipefail
cd "$(dirname "$0")/.."

IMAGE="${GLMAV_IMAGE:-localhost/glmav-observer:check}"
BASE_TAG=docker.io/library/python:3.11-slim-bookworm
SIM_SECONDS="${GLMAV_CHECK_SECONDS:-30}"
BUILD_ONLY=0
KEEP=0
for arg in "$@"; do
    case "$arg" in
        --build-only) BUILD_ONLY=1 ;;
        --keep) KEEP=1 ;;
        -h | --help)
            sed -n '2,22p' "$0"
            exit 0
            ;;
        *)
            echo "container-check: unknown argument: $arg" >&2
            exit 2
            ;;
    esac
done

podman_() {
    podman --cgroup-manager cgroupfs --events-backend file --runtime runc \
        ${GLMAV_PODMAN_STORAGE:+--storage-driver "$GLMAV_PODMAN_STORAGE"} "$@"
}
# runc cannot raise a container's rlimits above what this (nested) host allows.
ULIMITS=(--ulimit nofile=1024:1024 --ulimit nproc=4096:4096)

T0=$(date +%s)
log() { printf '[container-check %4ds] %s\n' "$(($(date +%s) - T0))" "$*" >&2; }
fail() {
    printf '[container-check] FAIL: %s\n' "$*" >&2
    exit 1
}

WORK="${GLMAV_CHECK_DIR:-$(mktemp -d /tmp/glmav-container-check.XXXXXX)}"
mkdir -p "$WORK"
CONTAINERS=()
cleanup() {
    local rc=$?
    if [[ ${#CONTAINERS[@]} -gt 0 && ($KEEP -eq 0) ]]; then
        podman_ rm -f -t 2 "${CONTAINERS[@]}" >/dev/null 2>&1 || true
    fi
    rm -f "$WORK/pip.conf" "$WORK/ca.crt"
    if [[ $rc -ne 0 ]]; then
        echo "[container-check] logs in $WORK" >&2
    fi
    exit "$rc"
}
trap cleanup EXIT

# ---- 1. the base image ------------------------------------------------------------------
t=$(date +%s)
scripts/build-base-image.sh
T_BASE=$(($(date +%s) - t))

# ---- 2. the app image -------------------------------------------------------------------
# pip configuration for the build, derived from this host: the index URLs pip would use here
# (pip config files and PIP_* environment), keeping only network indexes (a file:// or
# local path on the host does not exist inside the build), and the CA bundle.
host_pip_conf() {
    local pip_cmd=()
    if command -v pip3 >/dev/null; then
        pip_cmd=(pip3)
    elif python3 -m pip --version >/dev/null 2>&1; then
        pip_cmd=(python3 -m pip)
    fi
    {
        [[ ${#pip_cmd[@]} -gt 0 ]] && "${pip_cmd[@]}" config list 2>/dev/null || true
        env | grep -E '^PIP_(INDEX_URL|EXTRA_INDEX_URL|TRUSTED_HOST|DEFAULT_TIMEOUT|TIMEOUT)=' |
            sed -E 's/^PIP_([A-Z_]+)=(.*)$/:env:.\1=\2/' || true
    } | python3 -c '
import sys
values = {}
for line in sys.stdin:
    key, _, value = line.strip().partition("=")
    name = key.rpartition(".")[2].lower().replace("_", "-")
    value = value.strip().strip("\x27\"")
    if name == "default-timeout":
        name = "timeout"
    if name in ("index-url", "extra-index-url", "trusted-host", "timeout") and value:
        values[name] = value  # later lines (environment) override files, as in pip
keep = lambda url: url.startswith(("http://", "https://"))
print("[global]")
if keep(values.get("index-url", "")):
    print("index-url =", values["index-url"])
extra = [u for u in values.get("extra-index-url", "").split() if keep(u)]
if extra:
    print("extra-index-url =", " ".join(extra))
for name in ("trusted-host", "timeout"):
    if name in values:
        print(name, "=", values[name])
'
}
host_ca_bundle() {
    local f
    for f in "${PIP_CERT:-}" "${REQUESTS_CA_BUNDLE:-}" "${SSL_CERT_FILE:-}" \
        /etc/ssl/certs/ca-certificates.crt /etc/pki/tls/certs/ca-bundle.crt; do
        if [[ -n $f && -r $f ]]; then
            echo "$f"
            return
        fi
    done
}
(
    umask 077
    host_pip_conf >"$WORK/pip.conf"
    ca="$(host_ca_bundle)"
    if [[ -n $ca ]]; then cp "$ca" "$WORK/ca.crt"; else : >"$WORK/ca.crt"; fi
)

log "building $IMAGE (log: $WORK/build.log)"
t=$(date +%s)
# --format docker: the OCI image format has no HEALTHCHECK; --network host: the build's pip
# reaches the index like the host does; --pull=never: use the local base image.
if ! podman_ build --format docker --pull=never --network host "${ULIMITS[@]}" \
    --secret id=pipconf,src="$WORK/pip.conf" --secret id=cacert,src="$WORK/ca.crt" \
    --build-arg PYTHON_IMAGE="$BASE_TAG" -t "$IMAGE" -f Dockerfile . >"$WORK/build.log" 2>&1; then
    tail -n 40 "$WORK/build.log" >&2
    fail "podman build"
fi
T_BUILD=$(($(date +%s) - t))
SIZE_BYTES=$(podman_ image inspect --format '{{.Size}}' "$IMAGE")
log "image built in ${T_BUILD}s, size $((SIZE_BYTES / 1000000)) MB"

# ---- 3. image checks -------------------------------------------------------------------
# --no-healthcheck: podman schedules health checks with systemd timers, absent here; the
# check runs them itself (`podman healthcheck run`).
run_in_image() {
    podman_ run --rm --pull=never --network none --no-healthcheck "${ULIMITS[@]}" "$@"
}
user="$(run_in_image --entrypoint id "$IMAGE" -u)"
[[ $user != 0 ]] || fail "the image runs as root"
entry="$(podman_ image inspect --format '{{json .Config.Entrypoint}}' "$IMAGE")"
[[ $entry == '["glmav-observer"]' ]] || fail "entrypoint is $entry, expected glmav-observer"
health="$(podman_ image inspect --format '{{json .Config.Healthcheck}}' "$IMAGE")"
[[ $health == *Test* ]] || fail "no HEALTHCHECK in the image config ($health)"
run_in_image "$IMAGE" --help >/dev/null || fail "glmav-observer --help"
run_in_image --entrypoint glmav-sitl "$IMAGE" --help >/dev/null || fail "glmav-sitl --help"
# The installed versions are the pinned ones.
run_in_image --entrypoint pip "$IMAGE" freeze --exclude glmav-observer 2>/dev/null |
    sort >"$WORK/freeze.txt"
grep -E '^[A-Za-z0-9]' constraints.txt | sort | diff -u - "$WORK/freeze.txt" >&2 ||
    fail "installed packages differ from constraints.txt"
log "image checks passed (uid $user, entrypoint $entry)"

if [[ $BUILD_ONLY -eq 1 ]]; then
    printf 'container-check: build ok; base %ss, build %ss, image %s MB\n' \
        "$T_BASE" "$T_BUILD" "$((SIZE_BYTES / 1000000))"
    exit 0
fi

fail "the stack part is not written yet"
