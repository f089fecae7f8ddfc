"""Modbus RTU relay boards: the laser relay is one coil of a Modbus slave.

Protocol (Modbus Application Protocol v1.1b3 and Modbus over Serial Line v1.02):

* frame: ``slave function data... crc_lo crc_hi``; CRC-16/MODBUS (reflected polynomial
  0xA001, initial value 0xFFFF) over everything before it, sent low byte first;
* write single coil, function 05: ``slave 05 addr_hi addr_lo FF 00`` (on) or ``00 00``
  (off); a normal answer echoes the request byte for byte;
* read coils, function 01: ``slave 01 addr_hi addr_lo 00 01``; the answer is
  ``slave 01 01 bits crc``, bit 0 of ``bits`` being the coil asked for;
* exception answer: ``slave (function | 0x80) code crc`` (5 bytes), e.g. code 02 for an
  illegal data address (no such coil).

Known vector (a relay board's manual, quoted by huynguyen2310/IO-Box):
``01 05 00 00 FF 00 8C 3A`` switches coil 0 of slave 1 on; ``01 01 00 00 00 08 3D CC``
reads 8 coils and ``01 01 01 41 91 B8`` is an answer (coils 0 and 6 on).

Optional hardware dead man's switch (URI option ``pulse=SECONDS``): boards with Waveshare's
"flash on" command (Waveshare Modbus RTU Relay and compatible boards; a vendor extension of
function 05) take ``slave 05 02 ch t_hi t_lo`` as "relay ``ch`` on for t tenths of a second,
then off by itself" and echo it like any write-coil request, e.g. ``01 05 02 00 00 07 8D B0``
(relay 0 on for 0.7 s). With ``pulse`` set, 'on' is sent that way and a keeper thread renews
it every pulse/3 s while the laser is meant to be on; 'off' is the ordinary write-coil 0000.
If the process dies (kill -9, OOM), hangs, or the cable is pulled, nobody renews and the
board switches the laser off within ``pulse`` seconds.

Frames are separated by at least 3.5 character times of silence on the line (1.75 ms above
19200 baud): the driver waits that long after the last byte it saw before each request.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import TYPE_CHECKING, Any

from edgedsm.devices.laser._serial import SerialRelay, hexdump
from edgedsm.devices.uri import RelaySpec
from edgedsm.errors import DeviceError

if TYPE_CHECKING:
    from serial import SerialBase

READ_COILS = 0x01
WRITE_SINGLE_COIL = 0x05
COIL_ON = 0xFF00
COIL_OFF = 0x0000
FLASH_ON_BASE = 0x0200  # Waveshare's "flash on": coil address 0x0200 + channel, value in 0.1 s
RENEWALS_PER_PULSE = 3   # renew three times per pulse: two renewals may fail before the board drops

log = logging.getLogger(__name__)

EXCEPTION_CODES = {
    0x01: "illegal function",
    0x02: "illegal data address (no such coil)",
    0x03: "illegal data value",
    0x04: "slave device failure",
    0x05: "acknowledge (still processing)",
    0x06: "slave device busy",
    0x08: "memory parity error",
    0x0A: "gateway path unavailable",
    0x0B: "gateway target device failed to respond",
}


def crc16(data: bytes) -> int:
    """CRC-16/MODBUS of ``data`` (poly 0xA001 reflected, init 0xFFFF) as an integer."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def frame(body: bytes) -> bytes:
    """Append the CRC, low byte first, to ``slave function data``."""
    return body + crc16(body).to_bytes(2, "little")


def check_frame(data: bytes) -> bytes:
    """Verify a received frame's CRC; return the frame without it."""
    if len(data) < 4:
        raise DeviceError(f"Modbus answer too short: {hexdump(data)}")
    body, crc = data[:-2], int.from_bytes(data[-2:], "little")
    if crc16(body) != crc:
        raise DeviceError(f"Modbus answer has a bad CRC (expected {crc16(body):04X}, "
                          f"got {crc:04X}): {hexdump(data)}")
    return body


def _check_args(slave: int, coil: int) -> None:
    if not 1 <= slave <= 247:
        raise ValueError(f"Modbus slave address must be 1..247, not {slave}")
    if not 0 <= coil <= 0xFFFF:
        raise ValueError(f"Modbus coil address must be 0..65535, not {coil}")


def encode_write_coil(slave: int, coil: int, on: bool) -> bytes:
    """Function 05: write single coil ``coil`` to FF00 (on) or 0000 (off)."""
    _check_args(slave, coil)
    value = COIL_ON if on else COIL_OFF
    return frame(bytes((slave, WRITE_SINGLE_COIL)) + coil.to_bytes(2, "big")
                 + value.to_bytes(2, "big"))


def encode_read_coils(slave: int, coil: int, count: int = 1) -> bytes:
    """Function 01: read ``count`` coils starting at ``coil``."""
    _check_args(slave, coil)
    if not 1 <= count <= 2000:
        raise ValueError(f"Modbus can read 1..2000 coils at once, not {count}")
    return frame(bytes((slave, READ_COILS)) + coil.to_bytes(2, "big") + count.to_bytes(2, "big"))


def encode_flash_on(slave: int, channel: int, pulse_s: float) -> bytes:
    """Waveshare "flash on": relay ``channel`` (0..255) on for ``pulse_s`` seconds, then off."""
    _check_args(slave, channel)
    tenths = round(pulse_s * 10)
    if not 0 <= channel <= 0xFF or not 1 <= tenths <= 0xFFFF:
        raise ValueError(f"flash on needs channel 0..255 and 0.1..6553.5 s, not {channel}, {pulse_s} s")
    return frame(bytes((slave, WRITE_SINGLE_COIL)) + (FLASH_ON_BASE + channel).to_bytes(2, "big")
                 + tenths.to_bytes(2, "big"))


def answer_length(head: bytes) -> int:
    """Total length of an answer from its first 3 bytes (slave, function, next byte)."""
    if len(head) < 3:
        raise ValueError("need the first 3 bytes of the answer")
    function = head[1]
    if function & 0x80:
        return 5
    if function == WRITE_SINGLE_COIL:
        return 8
    if function == READ_COILS:
        return 3 + head[2] + 2
    raise DeviceError(f"Modbus answer with unexpected function {function:#04x}: {hexdump(head)}")


def _check_header(body: bytes, slave: int, function: int, answer: bytes) -> None:
    if body[0] != slave:
        raise DeviceError(f"Modbus answer from slave {body[0]}, expected {slave}: "
                          f"{hexdump(answer)}")
    if body[1] == function | 0x80:
        code = body[2]
        meaning = EXCEPTION_CODES.get(code, "unknown exception")
        raise DeviceError(f"Modbus slave {slave} refused function {function:02X} with "
                          f"exception {code:02X} ({meaning})")
    if body[1] != function:
        raise DeviceError(f"Modbus answer for function {body[1]:02X}, expected "
                          f"{function:02X}: {hexdump(answer)}")


def decode_write_coil(answer: bytes, request: bytes) -> None:
    """Check the answer to a write-single-coil request: it must echo the request."""
    body = check_frame(answer)
    _check_header(body, request[0], WRITE_SINGLE_COIL, answer)
    if answer != request:
        raise DeviceError(f"Modbus write-coil answer does not echo the request "
                          f"({hexdump(request)}): {hexdump(answer)}")


def decode_read_coils(answer: bytes, slave: int, count: int = 1) -> list[bool]:
    """The coil states (first coil first) from the answer to ``encode_read_coils``."""
    body = check_frame(answer)
    _check_header(body, slave, READ_COILS, answer)
    expected = (count + 7) // 8
    if body[2] != expected or len(body) != 3 + expected:
        raise DeviceError(f"Modbus read-coils answer carries {body[2]} data bytes, expected "
                          f"{expected}: {hexdump(answer)}")
    bits = int.from_bytes(body[3:], "little")
    return [bool(bits >> i & 1) for i in range(count)]


def silent_interval(baud: int) -> float:
    """Seconds of silence that separate two RTU frames: 3.5 characters, >= 1.75 ms."""
    # 11 bits per character (start, 8 data, parity or second stop, stop).
    return 1.75e-3 if baud > 19200 else 3.5 * 11 / baud


class ModbusCoilRelay(SerialRelay):
    """One coil of a Modbus RTU slave; readback with function 01."""

    protocol = "modbus"
    supports_readback = True

    def __init__(self, port: SerialBase, *, channel: int, timeout: float = 0.5,
                 verify: bool = True, description: str | None = None, slave: int = 1,
                 pulse: float | None = None) -> None:
        _check_args(slave, channel)
        if pulse is not None:
            encode_flash_on(slave, channel, pulse)  # refuses what the board cannot do
        name = getattr(port, "portstr", None) or getattr(port, "port", None) or "serial port"
        super().__init__(port, channel=channel, timeout=timeout, verify=verify,
                         description=description
                         or f"modbus slave {slave} coil {channel} on {name}")
        self.slave = slave
        self._gap = silent_interval(int(getattr(port, "baudrate", 9600) or 9600))
        self._last_activity = 0.0
        self.pulse = pulse
        self._keeper_stop: threading.Event | None = None

    @classmethod
    def _spec_options(cls, spec: RelaySpec) -> dict[str, Any]:
        return {"slave": spec.options.get("slave", 1), "pulse": spec.options.get("pulse")}

    def _transact(self, request: bytes, what: str) -> bytes:
        wait = self._last_activity + self._gap - time.monotonic()
        if wait > 0:
            time.sleep(wait)
        try:
            deadline = self._send(request)
            head = self._read_exact(3, deadline, what)
            if head[0] != request[0]:  # fail fast on noise rather than wait for its "length"
                raise DeviceError(f"{self.description}: answer to {what} is not from slave "
                                  f"{request[0]}: {hexdump(head)}")
            rest = self._read_exact(answer_length(head) - 3, deadline, what)
        finally:
            self._last_activity = time.monotonic()
        return head + rest

    def _do_switch(self, on: bool) -> None:
        if self.pulse is not None and on:
            self._flash_on()
            self._start_keeper()
            return
        self._stop_keeper()
        request = encode_write_coil(self.slave, self.channel, on)
        answer = self._transact(request, f"write coil {self.channel} (function 05)")
        decode_write_coil(answer, request)

    def _do_close(self) -> None:
        self._stop_keeper()  # the board switches off by itself within pulse s if still on
        super()._do_close()

    # -- pulse mode: the board's own timer switches off unless renewed ----------------------

    def _flash_on(self) -> None:
        assert self.pulse is not None
        request = encode_flash_on(self.slave, self.channel, self.pulse)
        answer = self._transact(request, f"flash on relay {self.channel} for {self.pulse:g} s")
        decode_write_coil(answer, request)

    def _start_keeper(self) -> None:
        if self._keeper_stop is not None and not self._keeper_stop.is_set():
            return  # already renewing
        stop = self._keeper_stop = threading.Event()
        threading.Thread(target=self._keep_on, args=(stop,), daemon=True,
                         name=f"edgedsm-relay-pulse-{self.channel}").start()

    def _stop_keeper(self) -> None:
        # never joins: the keeper may be waiting for the lock the caller holds
        if self._keeper_stop is not None:
            self._keeper_stop.set()

    def _keep_on(self, stop: threading.Event) -> None:
        assert self.pulse is not None
        while not stop.wait(self.pulse / RENEWALS_PER_PULSE):
            with self._lock:
                if stop.is_set() or self.closed or self._commanded is not True:
                    return
                try:
                    self._flash_on()
                except DeviceError as exc:
                    # Not renewed: the board switches the laser off within pulse s by itself,
                    # so the state is unknown, not "on"; the next on() starts a new keeper.
                    self._commanded = None
                    stop.set()
                    log.error("%s: could not renew the %g s pulse (the board will switch off by "
                              "itself): %s", self.description, self.pulse, exc)
                    return

    def _do_read_state(self) -> bool:
        request = encode_read_coils(self.slave, self.channel, 1)
        answer = self._transact(request, f"read coil {self.channel} (function 01)")
        return decode_read_coils(answer, self.slave, 1)[0]
