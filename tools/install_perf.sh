#!/usr/bin/env bash
# Install Linux perf (Debian package `linux-perf`) for tools/kernel_profile.py.
# Needs root (or sudo); does nothing when a perf binary is already on PATH.
set -euo pipefail
if command -v perf >/dev/null 2>&1; then
    echo "perf already installed: $(command -v perf)"
    exit 0
fi
SUDO=
if [ "$(id -u)" -ne 0 ]; then
    SUDO=sudo
fi
$SUDO apt-get update
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y --no-install-recommends linux-perf
command -v perf
