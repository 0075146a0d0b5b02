#!/bin/sh
# Compiles every board translation unit (firmware/src, firmware/lib, the models) for the Nano 33 BLE with the
# nano33ble variant's flags in PlatformIO's order plus platformio.ini's flags/unflags, without PlatformIO;
# prints text/data/bss per object; fails on any warning or error in our units, on soft-float/double helpers,
# or on a float ABI the variant's prebuilt libraries do not share. Compiles, does not link (no libmbed.a).
#   scripts/board-build.sh --core ArduinoCore-mbed-DIR --ble ArduinoBLE-DIR [--out DIR] [--env ENV] [--no-framework]
# The core dir needs cores/arduino/api (ArduinoCore-API's api/, as in the released core). Details:
# scripts/board_build.py.
set -eu
HERE=$(cd "$(dirname "$0")" && pwd)
exec python3 "$HERE/board_build.py" "$@"
