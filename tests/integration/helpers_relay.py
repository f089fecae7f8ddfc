"""Shared pieces of the relay integration tests: socat PTY pairs and emulated relay boards
that check every byte (used by test_relays_pty.py and test_daemon_e2e.py).

socat is required: without it the tests using these FAIL (the README's test command installs it).
"""

from __future__ import annotations

import contextlib
import shutil
import subprocess
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
import serial

H = bytes.fromhex
START_TIMEOUT_S = 10.0  # socat links must appear within this


# -- socat ---------------------------------------------------------------------------------

def socat() -> str:
    path = shutil.which("socat")
    if path is None:
        pytest.fail("socat is not installed, so the relay PTY tests cannot run: install it "
                    "with 'apt-get install -y socat' (the README's test command does)")
    return path


def wait_for(predicate: Callable[[], bool], timeout: float, what: str,
             process: subprocess.Popen[bytes] | None = None) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if process is not None and process.poll() is not None:
            err = process.stderr.read().decode(errors="replace") if process.stderr else ""
            pytest.fail(f"socat exited with {process.returncode} before {what}:\n{err}")
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.01)


def stop_process(process: subprocess.Popen[bytes]) -> None:
    if process.poll() is None:
        process.terminate()
        try:
            process.wait(timeout=5)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait(timeout=5)
    if process.stderr:
        process.stderr.close()


@dataclass
class PtyPair:
    """The two ends of a socat PTY pair and the socat process joining them."""

    app: str
    board: str
    process: subprocess.Popen[bytes]


@contextlib.contextmanager
def open_pty_pair(directory: Path) -> Iterator[PtyPair]:
    """A fresh socat PTY pair with its links in ``directory``: ``app`` for the driver,
    ``board`` for the emulator; socat is stopped on exit."""
    app, board = directory / "app", directory / "board"
    process = subprocess.Popen(
        [socat(), "-d", "-d", f"pty,raw,echo=0,link={app}", f"pty,raw,echo=0,link={board}"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        wait_for(lambda: app.exists() and board.exists(), START_TIMEOUT_S,
                 "socat's PTY links", process)
        yield PtyPair(str(app), str(board), process)
    finally:
        stop_process(process)


# -- emulated boards -----------------------------------------------------------------------

class EmulatedBoard(threading.Thread):
    """A relay board on the far end of the PTY: strict about bytes, answers like the real one.

    ``mode``: ``normal``; ``silent`` (a dead board: reads, never answers, never switches);
    ``garbage`` (answers nonsense); ``stuck`` (answers normally, the contact never moves).
    Every complete frame received is kept in ``received``; protocol violations go to
    ``errors`` (the fixture asserts there are none).
    """

    readback = True

    def __init__(self, path: str, channel: int) -> None:
        super().__init__(daemon=True, name=f"emulated-{type(self).__name__}")
        self.port = serial.Serial(path, timeout=0.02)
        self.channel = channel
        self.mode = "normal"
        self.is_on = False
        self.received: list[bytes] = []
        self.errors: list[str] = []
        self._buffer = bytearray()
        self._halt = threading.Event()
        self._lock = threading.Lock()

    # -- thread plumbing --
    def run(self) -> None:
        while not self._halt.is_set():
            try:
                chunk = self.port.read(max(1, self.port.in_waiting))
            except (serial.SerialException, OSError) as exc:
                if not self._halt.is_set():
                    self.errors.append(f"port failed: {exc}")
                return
            if chunk:
                self._buffer += chunk
                try:
                    self.consume()
                except Exception as exc:  # keep the report; a dead thread would hide it
                    self.errors.append(f"emulator crashed: {exc!r}")

    def stop(self) -> None:
        self._halt.set()
        self.join(5)
        self.port.close()

    def frames(self) -> list[bytes]:
        with self._lock:
            return list(self.received)

    def wait_frames(self, count: int, timeout: float = 5.0) -> list[bytes]:
        """Frames received, once there are at least ``count`` (boards that never answer)."""
        wait_for(lambda: len(self.frames()) >= count, timeout, f"{count} frames")
        return self.frames()

    def take(self, count: int) -> bytes | None:
        if len(self._buffer) < count:
            return None
        frame, self._buffer = bytes(self._buffer[:count]), self._buffer[count:]
        with self._lock:
            self.received.append(frame)
        return frame

    def answer(self, data: bytes) -> None:
        if self.mode == "silent":
            return
        if self.mode == "garbage":
            data = b"\x5a\xa5\x13\x37\xfe" + data[::-1]
        self.port.write(data)

    def switch(self, on: bool) -> None:
        if self.mode not in ("silent", "stuck"):
            self.is_on = on

    def consume(self) -> None:
        raise NotImplementedError


class LcusBoard(EmulatedBoard):
    """LCUS: A0 ch state checksum; never answers."""

    readback = False

    def consume(self) -> None:
        while (frame := self.take(4)) is not None:
            start, channel, state, check = frame
            if start != 0xA0 or channel != self.channel or state not in (0, 1) \
                    or check != (0xA0 + channel + state) & 0xFF:
                self.errors.append(f"bad LCUS frame {frame.hex(' ')}")
                continue
            self.switch(state == 1)


class NumatoBoard(EmulatedBoard):
    """Numato: ASCII line with CR; echo + '\\n\\r', the answer + '\\n\\r', then '>'."""

    def consume(self) -> None:
        while b"\r" in self._buffer:
            line = self.take(self._buffer.index(b"\r") + 1)
            assert line is not None
            command = line[:-1].decode("ascii", errors="replace")
            token = str(self.channel) if self.channel < 10 else chr(55 + self.channel)
            reply = command.encode() + b"\n\r"
            if command == f"relay on {token}":
                self.switch(True)
            elif command == f"relay off {token}":
                self.switch(False)
            elif command == f"relay read {token}":
                reply += (b"on" if self.is_on else b"off") + b"\n\r"
            else:
                self.errors.append(f"unexpected Numato command {line!r}")
            self.answer(reply + b">")


class KmtronicBoard(EmulatedBoard):
    """KMTronic: FF ch state (no answer); FF 09 00 -> one byte per relay."""

    def __init__(self, path: str, channel: int, relays: int = 8) -> None:
        super().__init__(path, channel)
        self.relays = relays

    def consume(self) -> None:
        while (frame := self.take(3)) is not None:
            header, channel, state = frame
            if header != 0xFF:
                self.errors.append(f"bad KMTronic frame {frame.hex(' ')}")
            elif frame == H("FF 09 00") and self.relays > 2:
                self.answer(bytes(int(self.is_on and ch == self.channel)
                                  for ch in range(1, self.relays + 1)))
            elif channel == self.channel and state in (0, 1):
                self.switch(state == 1)
            elif channel == self.channel and state == 3 and self.relays <= 2:
                self.answer(bytes((0xFF, channel, int(self.is_on))))
            else:
                self.errors.append(f"unexpected KMTronic frame {frame.hex(' ')}")


def crc16(data: bytes) -> bytes:
    """CRC-16/MODBUS written out again here, so the emulator does not trust the driver's."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return bytes((crc & 0xFF, crc >> 8))


class ModbusBoard(EmulatedBoard):
    """Modbus RTU slave with coils 0..15: functions 05 and 01, exception 02 outside."""

    def __init__(self, path: str, channel: int, slave: int = 7) -> None:
        super().__init__(path, channel)
        self.slave = slave
        self.coils = 16

    def consume(self) -> None:
        while (frame := self.take(8)) is not None:  # both requests used are 8 bytes long
            body, crc = frame[:6], frame[6:]
            if crc16(body) != crc:
                self.errors.append(f"bad Modbus CRC in {frame.hex(' ')}")
                continue
            slave, function = body[0], body[1]
            address, value = int.from_bytes(body[2:4], "big"), int.from_bytes(body[4:6], "big")
            if slave != self.slave:
                self.errors.append(f"Modbus frame for slave {slave}: {frame.hex(' ')}")
                continue
            if address >= self.coils:
                reply = bytes((slave, function | 0x80, 0x02))  # illegal data address
                self.answer(reply + crc16(reply))
            elif function == 0x05 and value in (0xFF00, 0x0000) and address == self.channel:
                self.switch(value == 0xFF00)
                self.answer(frame)
            elif function == 0x01 and value == 1 and address == self.channel:
                reply = bytes((slave, 0x01, 0x01, int(self.is_on)))
                self.answer(reply + crc16(reply))
            else:
                self.errors.append(f"unexpected Modbus frame {frame.hex(' ')}")


# The exact frames each board must receive for on(), off() and a readback, on the channels used by
# the tests (lcus 2, numato 11, kmtronic 3, modbus slave 7 coil 5: off the defaults, so that a
# driver ignoring channel= is caught).
ON = {"lcus": H("A0 02 01 A3"), "numato": b"relay on B\r", "kmtronic": H("FF 03 01"),
      "modbus": H("07 05 00 05 FF 00 9C 5D")}
OFF = {"lcus": H("A0 02 00 A2"), "numato": b"relay off B\r", "kmtronic": H("FF 03 00"),
       "modbus": H("07 05 00 05 00 00 DD AD")}
READ = {"numato": b"relay read B\r", "kmtronic": H("FF 09 00"),
        "modbus": H("07 01 00 05 00 01 ED AD")}
