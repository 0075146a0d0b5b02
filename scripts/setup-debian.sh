#!/usr/bin/env bash
# Debian packages the project needs beyond Python and a C++ compiler: the ARM cross toolchain (the signal
# core and the exported models are cross-compiled for the Cortex-M4F) and qemu (runs the bare-metal test
# image). Idempotent; uses sudo when not root.
set -euo pipefail
pkgs=(gcc-arm-none-eabi libnewlib-arm-none-eabi libstdc++-arm-none-eabi-newlib qemu-system-arm make)
missing=()
for p in "${pkgs[@]}"; do
  dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  echo "setup-debian: all packages present"
  exit 0
fi
SUDO=""
[ "$(id -u)" -eq 0 ] || SUDO="sudo"
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
