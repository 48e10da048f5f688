#!/usr/bin/env bash
# Install headless Chromium (Debian package `chromium`) for tools/rerun_screenshot.py.
# Needs root (or sudo); does nothing when a chromium binary is already on PATH.
exec bash "$(dirname "$0")/apt_install.sh" chromium chromium fonts-dejavu-core
