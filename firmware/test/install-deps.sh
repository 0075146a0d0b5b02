#!/bin/sh
# Debian packages for the firmware checks: the Arm cross compiler + newlib/libstdc++ and qemu (mps2-an386).
set -eu
SUDO=""
[ "$(id -u)" -ne 0 ] && SUDO=sudo
if command -v arm-none-eabi-gcc >/dev/null && command -v qemu-system-arm >/dev/null \
   && [ -d /usr/lib/arm-none-eabi/newlib ]; then
  exit 0
fi
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends \
  gcc-arm-none-eabi libnewlib-arm-none-eabi libstdc++-arm-none-eabi-newlib qemu-system-arm make
