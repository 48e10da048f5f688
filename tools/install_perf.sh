#!/usr/bin/env bash
# Install Linux perf (Debian package `linux-perf`) for tools/kernel_profile.py.
# Needs root (or sudo); does nothing when a perf binary is already on PATH.
exec bash "$(dirname "$0")/apt_install.sh" perf linux-perf
