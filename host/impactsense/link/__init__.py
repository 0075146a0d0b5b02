"""The host side of the board link: protocol (a thin layer over the C++ codec in `impactsense._link`),
transports (pyserial URLs and ptys, BLE through bleak), the pty emulator, the monitor and the recorder."""
