#!/usr/bin/env bash
# open3d links against libusb-1.0; install it with apt when we can, otherwise say how.
set -euo pipefail
if ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
    exit 0
fi
if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null; then
    echo "palpate set-up: installing libusb-1.0-0 (needed by open3d) with apt-get"
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libusb-1.0-0 >/dev/null
    exit 0
fi
echo "palpate set-up: open3d needs the system library libusb-1.0-0, which is missing." >&2
echo "Run:  sudo apt-get install -y libusb-1.0-0   (Debian/Ubuntu), then run make again." >&2
exit 1
