#!/usr/bin/env bash
# Packages the headless Rerun viewer screenshot test needs (tests/integration/glmav_observer/
# test_rerun_live.py): a virtual X server (Xvfb) and a software Vulkan driver (lavapipe, in
# mesa-vulkan-drivers). Idempotent: installs only what is missing. Debian/Ubuntu (apt-get).
set -euo pipefail

need=()
command -v Xvfb >/dev/null 2>&1 || need+=(xvfb)
compgen -G "/usr/share/vulkan/icd.d/lvp_icd*.json" >/dev/null || need+=(mesa-vulkan-drivers)
# the viewer loads libvulkan and libxkbcommon-x11 at run time
ldconfig -p | grep -q 'libvulkan\.so\.1' || need+=(libvulkan1)
ldconfig -p | grep -q 'libxkbcommon-x11\.so\.0' || need+=(libxkbcommon-x11-0)

if [ "${#need[@]}" -eq 0 ]; then
    echo "render deps present (Xvfb, lavapipe)"
    exit 0
fi

SUDO=""
if [ "$(id -u)" -ne 0 ]; then
    SUDO="sudo"
fi
echo "installing: ${need[*]}"
$SUDO apt-get update -q
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q --no-install-recommends "${need[@]}"
