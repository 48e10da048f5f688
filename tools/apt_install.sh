#!/usr/bin/env bash
# Install Debian packages for a tool: apt_install.sh BINARY PACKAGE [PACKAGE ...]
# installs the PACKAGEs unless BINARY is already on PATH, then prints BINARY's path.
# Needs root (or sudo).
set -euo pipefail
if [ "$#" -lt 2 ]; then
    echo "usage: $0 BINARY PACKAGE [PACKAGE ...]" >&2
    exit 2
fi
BINARY=$1
shift
if command -v "$BINARY" >/dev/null 2>&1; then
    echo "$BINARY already installed: $(command -v "$BINARY")"
    exit 0
fi
SUDO=
if [ "$(id -u)" -ne 0 ]; then
    SUDO=sudo
fi
$SUDO apt-get update
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y --no-install-recommends "$@"
command -v "$BINARY"
