#!/usr/bin/env bash
# Debian/Ubuntu packages impactsense needs beyond Python 3.10+.
#   --host      only what building and running the Python package needs: a C++ compiler, cmake, the Python
#               headers (python3-dev) and venv (python3-venv)
#   (default)   those, plus the firmware checks' tools: the ARM cross toolchain (the signal core and the
#               exported models are cross-compiled for the Cortex-M4F) and qemu (runs the bare-metal test image)
# Idempotent: checks first and installs only what is missing. Installing needs root, or sudo.
# Exit status: 0 everything present (or installed); 1 apt-get failed; 2 bad usage; 3 packages are missing and
# this user can neither install them (not root, no sudo) -- the script prints the command to run as root.
set -uo pipefail

usage() { sed -n '2,9p' "$0" | sed 's/^# \{0,1\}//'; }
host_only=0
for arg in "$@"; do
  case "$arg" in
    --host) host_only=1 ;;
    -h|--help) usage; exit 0 ;;
    *) echo "setup-debian: unknown option $arg" >&2; usage >&2; exit 2 ;;
  esac
done

if ! command -v dpkg >/dev/null 2>&1; then
  echo "setup-debian: not a Debian/Ubuntu system (no dpkg); install by hand: a C++17 compiler, cmake >= 3.18," \
       "the Python headers and venv module, and for the firmware checks arm-none-eabi-gcc and qemu-system-arm" >&2
  exit 0
fi

# The host part is checked by what works (a Python from python.org or a container needs no Debian python3-dev);
# the firmware part by package.
pyver=$(python3 -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")' 2>/dev/null || echo 3)
missing=()
command -v g++ >/dev/null 2>&1 || command -v c++ >/dev/null 2>&1 || missing+=(g++)
command -v cmake >/dev/null 2>&1 || missing+=(cmake)
python3 -c 'import os, sysconfig; assert os.path.isfile(os.path.join(sysconfig.get_paths()["include"], "Python.h"))' \
  >/dev/null 2>&1 || missing+=(python3-dev)
# Debian splits ensurepip per minor version (python3.11-venv).
python3 -c 'import ensurepip, venv' >/dev/null 2>&1 || missing+=(python3-venv "python${pyver}-venv")
if [ "$host_only" -eq 0 ]; then
  for p in make gcc-arm-none-eabi libnewlib-arm-none-eabi libstdc++-arm-none-eabi-newlib qemu-system-arm; do
    dpkg -s "$p" >/dev/null 2>&1 || missing+=("$p")
  done
fi
if [ ${#missing[@]} -eq 0 ]; then
  echo "setup-debian: all packages present"
  exit 0
fi

echo "setup-debian: missing: ${missing[*]}"
if [ "$(id -u)" -eq 0 ]; then
  SUDO=()
elif command -v sudo >/dev/null 2>&1; then
  SUDO=(sudo)
  echo "setup-debian: installing with sudo (it may ask for your password)"
else
  echo "setup-debian: installing needs root: you are not root and sudo is not installed. As root, run:" >&2
  echo "  apt-get update && apt-get install -y --no-install-recommends ${missing[*]}" >&2
  echo "then run this script again." >&2
  exit 3
fi
export DEBIAN_FRONTEND=noninteractive
if ! "${SUDO[@]}" apt-get update -qq || \
   ! "${SUDO[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "${missing[@]}"; then
  echo "setup-debian: apt-get failed; as root run: apt-get install -y ${missing[*]}" >&2
  exit 1
fi
echo "setup-debian: installed ${missing[*]}"
