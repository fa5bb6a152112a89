#!/bin/sh
# Installs the system libraries scanqa needs when they are missing.
# open3d's wheel links against libusb-1.0 (Debian package libusb-1.0-0).
set -e
missing=""
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
    missing="$missing libusb-1.0-0"
fi
[ -z "$missing" ] && exit 0
if command -v apt-get >/dev/null 2>&1; then
    echo "scanqa setup: installing system packages:$missing"
    SUDO=""
    [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -qq >/dev/null
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq $missing >/dev/null
else
    echo "scanqa setup: please install these system libraries with your package manager:$missing" >&2
    echo "  (open3d needs libusb-1.0; e.g. 'dnf install libusb1' or 'brew install libusb')" >&2
    exit 1
fi
