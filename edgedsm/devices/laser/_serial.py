"""Shared serial plumbing for relay boards: bounded reads, error mapping, port opening.

Every exchange has a deadline of ``timeout`` seconds from the moment the request is written.
Reads poll the port in short slices up to that deadline instead of trusting one blocking
read, because pyserial's URL backends time reads differently (``loop://`` waits per byte),
and a board that trickles garbage must not keep us waiting either.
"""

from __future__ import annotations

import contextlib
import errno
import os
import time
from typing import TYPE_CHECKING, Any

from edgedsm.devices.laser.base import LaserRelay
from edgedsm.devices.uri import RelaySpec
from edgedsm.errors import ConfigError, DeviceError, DeviceLost, DeviceTimeout

# pyserial is needed only to open a real port: without it the rest of edgedsm (and the
# simulated relay) keeps working, and opening a serial relay says what is missing.
try:
    import serial
except ImportError:  # pragma: no cover - pyserial is a declared dependency
    serial = None

if TYPE_CHECKING:
    from serial import SerialBase

POLL_S = 0.02  # read slice: bounds the overshoot past a deadline

_errors: list[type[BaseException]] = [OSError]
if serial is not None:
    _errors.append(serial.SerialException)  # includes SerialTimeoutException
try:  # POSIX ports also fail with termios.error (not an OSError), e.g. on a vanished PTY
    import termios

    _errors.append(termios.error)
except ImportError:  # pragma: no cover - Windows
    pass
PORT_ERRORS: tuple[type[BaseException], ...] = tuple(_errors)


def hexdump(data: bytes) -> str:
    """``A0 01 01 A2``-style dump for error messages (at most 32 bytes shown)."""
    shown = " ".join(f"{b:02X}" for b in data[:32])
    return shown + (f" ... ({len(data)} bytes)" if len(data) > 32 else "") if data else "nothing"


class PortLocked(DeviceError):
    """Another process holds the port's exclusive lock (a daemon running, hung or stopped);
    ``holder``: its PID where /proc/locks says (None: unknown)."""

    def __init__(self, message: str, port: str, holder: int | None) -> None:
        super().__init__(message)
        self.port = port
        self.holder = holder


def lock_holder(path: str) -> int | None:
    """The PID holding a lock on the file ``path`` (a device node; symlinks followed), from
    /proc/locks (None when it cannot tell: no /proc, the file gone, the holder in another
    PID namespace shows as 0)."""
    try:
        st = os.stat(path)
        with open("/proc/locks", encoding="ascii", errors="replace") as handle:
            lines = handle.read().splitlines()
    except OSError:
        return None
    for line in lines:
        fields = line.split()
        if len(fields) < 6 or "->" in fields:  # "->": a process waiting for the lock, not holding it
            continue
        try:
            major, minor, inode = fields[5].split(":")
            pid = int(fields[4])
            if (int(major, 16), int(minor, 16), int(inode)) == (os.major(st.st_dev), os.minor(st.st_dev), st.st_ino):
                return pid or None
        except ValueError:
            continue
    return None


def open_port(spec: RelaySpec, *, exclusive: bool = True, do_not_open: bool = False) -> SerialBase:
    """Open the spec's port with pyserial's ``serial_for_url`` (device paths and URLs alike).

    ``exclusive``: take the port's lock (flock), so that a technician's tool and the daemon
    never talk at once; a port another process holds is :class:`PortLocked`. Without it (only
    to switch off: ``edgedsm laser off``) the port is opened whoever holds it. ``do_not_open``:
    only check the URL and settings (ConfigError, as opening would say), touching nothing."""
    if serial is None:
        raise DeviceError("cannot open a serial relay: pyserial is not installed "
                          "(pip install pyserial)")
    kwargs: dict[str, Any] = {
        "baudrate": spec.baud,
        "bytesize": serial.EIGHTBITS,
        "parity": str(spec.options.get("parity", "N")),
        "stopbits": serial.STOPBITS_ONE,
        "timeout": POLL_S,
        "write_timeout": spec.timeout,
    }
    if not spec.is_url and exclusive:
        # A lock on the device keeps a technician's tool and the daemon from talking at once.
        kwargs["exclusive"] = True
    try:
        return serial.serial_for_url(spec.port, do_not_open=do_not_open, **kwargs)
    except ValueError as exc:  # pyserial's answer to a malformed URL or setting
        raise ConfigError(f"relay URI {spec.uri!r}: {exc}") from exc
    except PORT_ERRORS as exc:
        if "exclusive" in kwargs and getattr(exc, "errno", None) in (errno.EAGAIN, errno.EWOULDBLOCK):
            holder = lock_holder(spec.port)
            by = f"process {holder}" if holder else "another process"
            raise PortLocked(f"cannot open relay port {spec.port}: it is locked by {by} (a daemon still "
                             f"running? stop it first): {exc}", spec.port, holder) from exc
        raise DeviceError(f"cannot open relay port {spec.port}: {exc}") from exc


class SerialRelay(LaserRelay):
    """Base of the relay drivers that talk to a board over a serial port."""

    protocol: str = "serial"

    def __init__(self, port: SerialBase, *, channel: int, timeout: float = 0.5,
                 verify: bool = True, description: str | None = None) -> None:
        name = getattr(port, "portstr", None) or getattr(port, "port", None) or "serial port"
        super().__init__(verify=verify,
                         description=description
                         or f"{self.protocol} relay {channel} on {name}")
        self._port = port
        self.channel = channel
        self.timeout = timeout
        self._spec: RelaySpec | None = None  # set by from_spec: how to reopen the port
        self._exclusive = True  # and whether with its lock
        self._port_failed = False  # the port failed (board unplugged): reopened before the next request

    @classmethod
    def from_spec(cls, spec: RelaySpec, *, exclusive: bool = True) -> SerialRelay:
        """Open the port named by a parsed URI and build the driver on it (``exclusive``: see
        :func:`open_port`)."""
        port = open_port(spec, exclusive=exclusive)
        try:
            relay = cls(port, channel=spec.channel, timeout=spec.timeout, verify=spec.verify,
                        **cls._spec_options(spec))
        except BaseException:
            port.close()
            raise
        relay._spec, relay._exclusive = spec, exclusive
        return relay

    @classmethod
    def _spec_options(cls, spec: RelaySpec) -> dict[str, Any]:
        """Protocol-specific constructor arguments taken from the URI's options."""
        return {}

    # -- byte-level helpers for drivers -----------------------------------------------------

    def _reopen_if_failed(self) -> None:
        """A port that failed is dead for good (a USB board unplugged): open its path again, so a
        board plugged in again is used (raises DeviceError while it is still missing)."""
        if not self._port_failed or self._spec is None:
            return
        with contextlib.suppress(*PORT_ERRORS):
            self._port.close()
        self._port = open_port(self._spec, exclusive=self._exclusive)
        self._port_failed = False

    def _port_lost(self, exc: BaseException) -> DeviceLost:
        self._port_failed = True
        return DeviceLost(f"{self.description}: port failed: {exc}")

    def _send(self, data: bytes) -> float:
        """Write one request; return the deadline for its answer (time.monotonic())."""
        self._reopen_if_failed()
        try:
            # Drop stale bytes: an exchange cut short (timeout, signal) may have left an
            # answer behind that would otherwise be read as the answer to this request.
            self._port.reset_input_buffer()
            self._port.write(data)
            self._port.flush()
        except PORT_ERRORS as exc:
            if serial is not None and isinstance(exc, serial.SerialTimeoutException):
                # write_timeout expired: the port is there but takes nothing (flow control)
                raise DeviceTimeout(f"{self.description}: could not write within "
                                    f"{self.timeout} s ({exc})") from exc
            raise self._port_lost(exc) from exc
        return time.monotonic() + self.timeout

    def _read_chunk(self, wanted: int) -> bytes:
        try:
            waiting = self._port.in_waiting
            return self._port.read(max(1, min(waiting, wanted)))
        except PORT_ERRORS as exc:
            raise self._port_lost(exc) from exc

    def _no_answer(self, what: str, got: bytes) -> DeviceError:
        if not got:
            return DeviceTimeout(f"{self.description}: no answer within {self.timeout} s "
                                 f"to {what}")
        return DeviceError(f"{self.description}: incomplete answer to {what} within "
                           f"{self.timeout} s: {hexdump(got)}")

    def _read_exact(self, count: int, deadline: float, what: str) -> bytes:
        """Read exactly ``count`` bytes before ``deadline`` or raise."""
        buf = bytearray()
        while len(buf) < count and time.monotonic() < deadline:
            buf += self._read_chunk(count - len(buf))
        if len(buf) < count:
            raise self._no_answer(what, bytes(buf))
        return bytes(buf)

    def _read_until(self, terminator: bytes, limit: int, deadline: float, what: str) -> bytes:
        """Read up to and including ``terminator`` (at most ``limit`` bytes) or raise."""
        buf = bytearray()
        while time.monotonic() < deadline:
            buf += self._read_chunk(limit - len(buf))
            if buf.endswith(terminator):
                return bytes(buf)
            if len(buf) >= limit:
                raise DeviceError(f"{self.description}: answer to {what} is too long "
                                  f"(no {terminator!r} in {limit} bytes): {hexdump(bytes(buf))}")
        raise self._no_answer(what, bytes(buf))

    def _do_close(self) -> None:
        self._port.close()
