"""The Modbus relay's hardware dead man's switch (URI option pulse=SECONDS): 'on' is Waveshare's
"flash on" (the board switches off by itself after the pulse) renewed by a keeper thread. Against
an emulated board on a socat PTY pair, byte for byte, including a real kill -9 of the process
that switched the laser on: the board goes dark within the pulse with nobody switching it off.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from helpers_relay import OFF, READ, H, ModbusBoard, crc16, open_pty_pair

from edgedsm.devices.laser import LaserSafety, open_relay
from edgedsm.errors import ConfigError

pytestmark = [pytest.mark.integration, pytest.mark.timeout(60)]

PULSE_S = 1.0
FLASH_ON = H("07 05 02 05 00 0A") + crc16(H("07 05 02 05 00 0A"))  # slave 7, relay 5, 10 tenths
URI_QUERY = f"protocol=modbus&slave=7&channel=5&pulse={PULSE_S}"


class FlashingBoard(ModbusBoard):
    """A Modbus relay board with Waveshare's "flash on" (coil 0x0200 + relay, value in 0.1 s)."""

    def __init__(self, path: str, channel: int, slave: int = 7) -> None:
        super().__init__(path, channel, slave)
        self.off_at: float | None = None  # when the board's own timer opens the relay
        self.timed_out: list[float] = []   # monotonic times the timer switched the relay off
        threading.Thread(target=self._timer, daemon=True).start()

    def _timer(self) -> None:
        while not self._halt.is_set():
            with self._lock:
                if self.off_at is not None and time.monotonic() >= self.off_at:
                    self.off_at, self.is_on = None, False
                    self.timed_out.append(time.monotonic())
            time.sleep(0.005)

    def consume(self) -> None:
        while len(self._buffer) >= 8:
            request = bytes(self._buffer[:8])
            if request[1] == 0x05 and request[2] == 0x02:
                self.take(8)
                if crc16(request[:6]) != request[6:] or request[0] != self.slave or request[3] != self.channel:
                    self.errors.append(f"bad flash frame {request.hex(' ')}")
                    continue
                tenths = int.from_bytes(request[4:6], "big")
                if self.mode not in ("silent", "stuck"):
                    with self._lock:
                        self.is_on, self.off_at = True, time.monotonic() + tenths / 10
                self.answer(request)
                continue
            rest, self._buffer = self._buffer[8:], self._buffer[:8]
            if request[1] == 0x05 and self.mode not in ("silent", "stuck"):
                with self._lock:
                    self.off_at = None  # an ordinary write cancels the flash
            super().consume()  # exactly this one ordinary frame
            self._buffer += rest


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[tuple[FlashingBoard, str]]:
    with open_pty_pair(tmp_path) as pair:
        board = FlashingBoard(pair.board, channel=5)
        board.start()
        try:
            yield board, f"serial:{pair.app}?{URI_QUERY}"
        finally:
            board.stop()
        assert board.errors == []


def test_on_is_a_renewed_pulse_and_off_is_plain_byte_exact(rig: tuple[FlashingBoard, str]) -> None:
    board, uri = rig
    with LaserSafety(open_relay(uri)) as laser:
        status = laser.on()
        assert status.on and status.confirmed
        time.sleep(2.5 * PULSE_S)  # longer than the pulse: only the renewals keep it on
        assert board.is_on and board.timed_out == []
        laser.off()
        frames = board.frames()
        assert frames[:3] == [OFF["modbus"], READ["modbus"], FLASH_ON]  # safety's off at start, then on
        renewals = frames[3:-2]
        assert renewals[0] == READ["modbus"] and set(renewals[1:]) == {FLASH_ON}
        assert 5 <= len(renewals) - 1 <= 9  # every PULSE_S/3 for 2.5 pulses: 7 or 8
        assert frames[-2:] == [OFF["modbus"], READ["modbus"]]
        assert not board.is_on
    settled = len(board.frames())
    time.sleep(PULSE_S)
    assert len(board.frames()) == settled  # the keeper stopped with off(): no more renewals


def test_kill_9_leaves_the_laser_off_within_the_pulse(rig: tuple[FlashingBoard, str]) -> None:
    board, uri = rig
    holder = ("import sys, time\nfrom edgedsm.devices.laser import open_relay\n"
              "relay = open_relay(sys.argv[1]); relay.on(); print('on', flush=True); time.sleep(60)\n")
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    with subprocess.Popen([sys.executable, "-c", holder, uri], stdout=subprocess.PIPE, text=True,
                          env=env) as process:
        try:
            assert process.stdout is not None and process.stdout.readline() == "on\n"
            time.sleep(1.5 * PULSE_S)
            assert board.is_on and board.timed_out == []  # renewed past the first pulse
            killed = time.monotonic()
            process.send_signal(signal.SIGKILL)
            process.wait(5)
        finally:
            if process.poll() is None:
                process.kill()
    deadline = killed + PULSE_S + 1.0
    while board.is_on and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not board.is_on, "the board did not switch the laser off by itself"
    delay = board.timed_out[0] - killed
    print(f"laser off {delay:.2f} s after kill -9 (pulse {PULSE_S} s)")
    assert 0 <= delay <= PULSE_S + 0.1


def test_a_failed_renewal_is_logged_and_the_board_drops_by_itself(
        rig: tuple[FlashingBoard, str], caplog: pytest.LogCaptureFixture) -> None:
    board, uri = rig
    with LaserSafety(open_relay(uri + "&timeout=0.2")) as laser:
        laser.on()
        board.mode = "silent"  # answers nothing and, being dead, times nothing either
        deadline = time.monotonic() + 3 * PULSE_S
        while "could not renew" not in caplog.text:
            assert time.monotonic() < deadline, "a renewal without an answer must be reported"
            time.sleep(0.02)
        sent = len(board.frames())
        board.mode = "normal"
        time.sleep(PULSE_S + 0.2)
        assert len(board.frames()) == sent  # the keeper gave up: nothing renews a pulse in doubt
        assert not board.is_on  # the board's own timer switched it off
        status = laser.state()
        assert (status.on, status.confirmed) == (False, True)


@pytest.mark.parametrize(("query", "reason"), [
    ("protocol=modbus&pulse=0.2", "pulse=0.2 must be >= 0.5 and <= 6553.5 seconds"),
    ("protocol=modbus&pulse=7000", "must be >= 0.5 and <= 6553.5"),
    ("protocol=modbus&pulse=1.25", "the board counts tenths of a second"),
    ("protocol=modbus&channel=256&pulse=1", "pulse= needs channel 0..255"),
    ("protocol=lcus&pulse=1", "unknown option 'pulse'"),
])
def test_bad_pulse_options_are_config_errors(query: str, reason: str) -> None:
    with pytest.raises(ConfigError, match=reason.replace(".", r"\.").replace("(", r"\(")):
        open_relay(f"serial:/dev/ttyUSB0?{query}")
