#!/bin/sh
# Cross-compiles the portable firmware + exported models for the Cortex-M4F, prints arm-none-eabi-size, and
# runs the bare-metal test image on qemu (mps2-an386). Exit code = the image's (0: all checks passed).
#   [PYTHON=python-with-impactsense] firmware/test/qemu/run.sh [BUILD_DIR] [--model-dir MODEL_DIR]
# Needs: arm-none-eabi-gcc, newlib, qemu-system-arm (scripts/setup-debian.sh) and the impactsense
# package (for the fixture: recorded drops + the host's expected values).
set -eu
HERE=$(cd "$(dirname "$0")" && pwd)
BUILD=${1:-$HERE/../../../build/qemu}
[ $# -gt 0 ] && shift
mkdir -p "$BUILD"
BUILD=$(cd "$BUILD" && pwd)
"${PYTHON:-python3}" "$HERE/gen_fixture.py" "$BUILD" "$@"
make -s -f "$HERE/Makefile" BUILD="$BUILD" -j2
exec qemu-system-arm -M mps2-an386 -nographic -monitor none -serial none \
  -semihosting-config enable=on,target=native ${QEMU_EXTRA:-} -kernel "$BUILD/test.elf"
