#!/usr/bin/env bash
# open3d's library links these system libraries even when nothing is drawn (docker/Dockerfile installs
# the same list); install the missing ones with apt when we can, otherwise say how.
set -euo pipefail
libraries=(libusb-1.0.so.0 libGL.so.1 libEGL.so.1 libX11.so.6 libudev.so.1 libidn2.so.0)
packages=(libusb-1.0-0 libgl1 libegl1 libx11-6 libudev1 libidn2-0)
ldconfig_cmd=$(command -v ldconfig || echo /sbin/ldconfig)  # not on a non-root user's PATH on Debian
known=$("$ldconfig_cmd" -p 2>/dev/null || true)
missing=()
for i in "${!libraries[@]}"; do
    grep -qF "${libraries[$i]}" <<<"$known" || missing+=("${packages[$i]}")
done
if [ ${#missing[@]} -eq 0 ]; then
    exit 0
fi
if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null; then
    echo "palpate set-up: installing ${missing[*]} (needed by open3d) with apt-get"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${missing[@]}" >/dev/null
    exit 0
fi
echo "palpate set-up: open3d needs the system libraries of ${missing[*]}, which are missing." >&2
echo "Run:  sudo apt-get install -y ${missing[*]}   (Debian/Ubuntu), then run make again." >&2
exit 1
