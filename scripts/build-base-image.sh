#!/usr/bin/env bash
# Build a local stand-in for the official python:3.11-slim-bookworm image and tag it
# docker.io/library/python:3.11-slim-bookworm, so that the real Dockerfile builds with
# `--pull=never` on machines that cannot pull from Docker Hub (see docs/container.md).
#
# The stand-in is a Debian bookworm root made with debootstrap (variant minbase) plus
# Debian's python3 (3.11), python3-venv, python3-pip and ca-certificates, laid out like the
# official image: /usr/local/bin/{python,python3,python3.11,pip,pip3,pip3.11}, LANG=C.UTF-8,
# no EXTERNALLY-MANAGED marker (the official image's pip installs freely), CMD ["python3"].
#
# Debian packages come from the mirror the HOST's apt is configured with (read at run time
# from /etc/apt/sources.list and /etc/apt/sources.list.d/*.sources|*.list); set
# GLMAV_DEBIAN_MIRROR to override. No mirror address is stored in this repository.
#
# Usage: scripts/build-base-image.sh [--force]
#   --force   rebuild even if the tag already exists
# Environment: GLMAV_PODMAN_STORAGE (storage driver, default: podman's default),
#              GLMAV_DEBIAN_MIRROR, GLMAV_BASE_TAG (default docker.io/library/python:3.11-slim-bookworm)
set -euo pipefail

BASE_TAG="${GLMAV_BASE_TAG:-docker.io/library/python:3.11-slim-bookworm}"
SUITE=bookworm
FORCE=0
for arg in "$@"; do
    case "$arg" in
        --force) FORCE=1 ;;
        -h | --help)
            sed -n '2,20p' "$0"
            exit 0
            ;;
        *)
            echo "build-base-image: unknown argument: $arg" >&2
            exit 2
            ;;
    esac
done

podman_() {
    podman --cgroup-manager cgroupfs --events-backend file --runtime runc \
        ${GLMAV_PODMAN_STORAGE:+--storage-driver "$GLMAV_PODMAN_STORAGE"} "$@"
}

# runc cannot raise the container's rlimits above what this (nested) host allows.
ULIMITS=(--ulimit nofile=1024:1024 --ulimit nproc=4096:4096)

log() { printf '[build-base-image] %s\n' "$*" >&2; }

if [[ $(id -u) -ne 0 ]]; then
    echo "build-base-image: debootstrap needs root (run with sudo)" >&2
    exit 1
fi
for tool in debootstrap podman tar; do
    if ! command -v "$tool" >/dev/null; then
        echo "build-base-image: '$tool' not found; apt-get install podman buildah runc debootstrap" >&2
        exit 1
    fi
done

if [[ $FORCE -eq 0 ]] && podman_ image exists "$BASE_TAG"; then
    log "$BASE_TAG already present (use --force to rebuild)"
    exit 0
fi

# The first 'deb' source of the host whose suites include bookworm (deb822 or one-line format).
host_debian_mirror() {
    local f
    shopt -s nullglob
    for f in /etc/apt/sources.list.d/*.sources; do
        awk -v suite="$SUITE" '
            function flush() { if (is_deb && has_suite && uri != "") { print uri; found = 1; exit } }
            /^[[:space:]]*$/ { flush(); is_deb = 0; has_suite = 0; uri = ""; next }
            /^[[:space:]]*#/ { next }
            tolower($1) == "types:" { for (i = 2; i <= NF; i++) if ($i == "deb") is_deb = 1 }
            tolower($1) == "uris:" { uri = $2 }
            tolower($1) == "suites:" { for (i = 2; i <= NF; i++) if ($i == suite) has_suite = 1 }
            tolower($1) == "enabled:" && tolower($2) == "no" { is_deb = 0 }
            END { if (!found) flush() }
        ' "$f"
    done
    for f in /etc/apt/sources.list /etc/apt/sources.list.d/*.list; do
        [[ -r $f ]] || continue
        # deb [options] URI SUITE COMPONENTS...
        sed -e 's/\[[^]]*\]//' "$f" | awk -v suite="$SUITE" '$1 == "deb" && $3 == suite { print $2 }'
    done
    shopt -u nullglob
}

MIRROR="${GLMAV_DEBIAN_MIRROR:-$(host_debian_mirror | head -n 1)}"
if [[ -z $MIRROR ]]; then
    echo "build-base-image: no Debian $SUITE source in the host's apt configuration;" \
        "set GLMAV_DEBIAN_MIRROR" >&2
    exit 1
fi
KEYRING=/usr/share/keyrings/debian-archive-keyring.gpg
KEYRING_ARGS=()
[[ -r $KEYRING ]] && KEYRING_ARGS=(--keyring="$KEYRING")

previous_id="$(podman_ image inspect --format '{{.Id}}' "$BASE_TAG" 2>/dev/null || true)"
ROOT="$(mktemp -d /var/tmp/glmav-base-root.XXXXXX)"
cleanup() { rm -rf --one-file-system "$ROOT"; }
trap cleanup EXIT

start=$(date +%s)
log "debootstrap $SUITE (minbase + python3) from the host's apt mirror into $ROOT"
debootstrap --variant=minbase "${KEYRING_ARGS[@]}" \
    --include=python3,python3-venv,python3-pip,ca-certificates,netbase,tzdata \
    "$SUITE" "$ROOT" "$MIRROR" >"$ROOT.debootstrap.log" 2>&1 || {
    tail -n 40 "$ROOT.debootstrap.log" >&2
    rm -f "$ROOT.debootstrap.log"
    exit 1
}
rm -f "$ROOT.debootstrap.log"

py_version="$(chroot "$ROOT" /usr/bin/python3 -c 'import platform; print(platform.python_version())')"
case "$py_version" in
    3.11.*) ;;
    *)
        echo "build-base-image: expected Python 3.11 in $SUITE, got $py_version" >&2
        exit 1
        ;;
esac

# Lay the root out like the official image.
mkdir -p "$ROOT/usr/local/bin"
for name in python3.11 python3 python; do
    ln -sf /usr/bin/python3.11 "$ROOT/usr/local/bin/$name"
done
for name in pip pip3 pip3.11; do
    printf '#!/bin/sh\nexec /usr/bin/python3.11 -m pip "$@"\n' >"$ROOT/usr/local/bin/$name"
    chmod 0755 "$ROOT/usr/local/bin/$name"
done
rm -f "$ROOT"/usr/lib/python3.11/EXTERNALLY-MANAGED
# Inside the image apt uses the standard Debian host name, as in the official image.
rm -f "$ROOT/etc/apt/sources.list"
cat >"$ROOT/etc/apt/sources.list.d/debian.sources" <<'EOF'
Types: deb
URIs: http://deb.debian.org/debian
Suites: bookworm bookworm-updates
Components: main
Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg
EOF
rm -rf "$ROOT"/var/lib/apt/lists/* "$ROOT"/var/cache/apt/archives/*.deb \
    "$ROOT"/var/cache/apt/*.bin "$ROOT"/var/log/*.log "$ROOT"/usr/share/doc/* \
    "$ROOT"/usr/share/man/* "$ROOT"/usr/share/info/*
find "$ROOT/usr/lib/python3.11" -name __pycache__ -type d -prune -exec rm -rf {} +

log "importing as $BASE_TAG (Python $py_version)"
tar --numeric-owner --xattrs -C "$ROOT" -c . | podman_ import --quiet \
    --change 'ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
    --change 'ENV LANG=C.UTF-8' \
    --change "ENV PYTHON_VERSION=$py_version" \
    --change 'CMD ["python3"]' \
    --message "local stand-in for python:3.11-slim-bookworm (debootstrap $SUITE, Debian python3)" \
    - "$BASE_TAG" >/dev/null

if [[ -n $previous_id ]]; then podman_ rmi "$previous_id" >/dev/null 2>&1 || true; fi
podman_ run --rm --pull=never --network none "${ULIMITS[@]}" "$BASE_TAG" python -c \
    'import ssl, sys, venv; assert sys.version_info[:2] == (3, 11), sys.version; print("base ok", sys.version.split()[0])'
log "done in $(($(date +%s) - start)) s; size: $(podman_ image inspect --format '{{.Size}}' "$BASE_TAG") bytes"
