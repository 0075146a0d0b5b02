"""Transports with pyserial's interface (`read(n)`, `write(b)`, `close()`, `timeout`, `is_open`).

The protocol knows none of them: a real board or the pty emulator is a pyserial port (`/dev/ttyACM0`,
`/dev/pts/N`, `loop://`); BLE is `BleTransport`, which turns the report notifications (each one report
body with a version byte, impactlink.h) back into serial frames so one decoder serves both.
"""

from __future__ import annotations

import asyncio
import queue
import threading

from ..errors import ConfigError
from . import protocol


class PortClosed(Exception):
    """The other end went away (board unplugged, emulator finished)."""


def open_serial(port: str, baudrate: int = 115200, timeout: float = 0.2):
    import serial

    return serial.serial_for_url(port, baudrate=baudrate, timeout=timeout)


def read_some(port, n: int = 4096) -> bytes:
    """Reads what is there (up to n bytes); raises PortClosed when the port has gone."""
    import serial

    try:
        waiting = getattr(port, "in_waiting", 0) or 1
        data = port.read(min(max(waiting, 1), n))
    except (serial.SerialException, OSError) as exc:
        raise PortClosed(str(exc)) from exc
    if not getattr(port, "is_open", True):
        raise PortClosed("port closed")
    return data


# BLE: the custom service of firmware/src/main.cpp.
SERVICE_UUID = "6e5a0001-8a3c-4b8e-9d2f-1c0ffee10001"
REPORT_UUID = "6e5a0002-8a3c-4b8e-9d2f-1c0ffee10001"
CONFIG_UUID = "6e5a0003-8a3c-4b8e-9d2f-1c0ffee10001"


class BleTransport:
    """A pyserial-like port over BLE notifications (bleak). `client_factory(address)` makes the
    BleakClient; tests pass a double. Reads return serial frames re-built from the notifications by the C++
    codec; writes (commands) go to the config characteristic."""

    def __init__(self, address: str, timeout: float = 0.2, client_factory=None):
        self.timeout = timeout
        self._q: queue.Queue = queue.Queue()
        self._buf = b""
        self.is_open = False
        self.bad_payloads = 0          # notifications that are not a report of this host's version
        self.ble_version_errors = 0    # ... of them, those of another protocol version (its first byte)
        self.ble_other_version = 0     # that version (0: none seen)
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, daemon=True)
        self._thread.start()
        if client_factory is None:
            try:
                from bleak import BleakClient, BleakScanner
            except ImportError:
                raise ConfigError("--ble needs the bleak package: pip install 'impactsense[ble]' "
                                  "(or pip install bleak)") from None

            target = address
            if len(address.split(":")) != 6:  # a name: find the device first
                target = self._run(BleakScanner.find_device_by_name(address, timeout=10.0))
                if target is None:
                    raise PortClosed(f"no BLE device named {address!r}")
            client_factory = lambda dev: BleakClient(dev, disconnected_callback=lambda _c: self.disconnected())  # noqa: E731
            address = target
        self._client = client_factory(address)
        self._run(self._connect())
        self.is_open = True

    def _run(self, coro, timeout: float = 30.0):
        return asyncio.run_coroutine_threadsafe(coro, self._loop).result(timeout)

    async def _connect(self):
        await self._client.connect()
        await self._client.start_notify(REPORT_UUID, self._on_notify)

    def _on_notify(self, _handle, data) -> None:
        report = protocol.parse_ble_payload(bytes(data))
        if report is None:
            self.bad_payloads += 1
            if len(data) and data[0] != protocol.VERSION:
                self.ble_version_errors += 1
                self.ble_other_version = int(data[0])
            return
        self._q.put(protocol.encode_report(report))

    def disconnected(self) -> None:
        """Called by the client's disconnect callback (or a test)."""
        self._q.put(None)

    @property
    def in_waiting(self) -> int:
        return len(self._buf)

    def read(self, n: int = 1) -> bytes:
        if not self._buf:
            try:
                item = self._q.get(timeout=self.timeout)
            except queue.Empty:
                return b""
            if item is None:
                self.is_open = False
                raise PortClosed("BLE disconnected")
            self._buf = item
        out, self._buf = self._buf[:n], self._buf[n:]
        return out

    def write(self, data: bytes) -> int:
        self._run(self._client.write_gatt_char(CONFIG_UUID, bytes(data), response=True))
        return len(data)

    def close(self) -> None:
        if self.is_open:
            try:
                self._run(self._client.disconnect(), timeout=5.0)
            finally:
                self.is_open = False
        self._loop.call_soon_threadsafe(self._loop.stop)
