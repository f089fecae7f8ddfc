"""edgedsm.testing: the shipped contract checks pass a minimal driver and catch broken ones.

The minimal drivers here are the ones docs/drivers.md shows, written as a user would.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from edgedsm.devices.camera import Camera
from edgedsm.devices.laser import LaserRelay
from edgedsm.errors import DeviceTimeout
from edgedsm.frames import Frame, FrameFormat
from edgedsm.testing import (
    CAMERA_CHECKS,
    RELAY_CHECKS,
    RelayRig,
    check_camera_contract,
    check_frames,
    check_relay_contract,
)


class CountingCamera(Camera):
    """A 4x6 uint16 camera whose pixels count frames (10 significant bits)."""

    kind = "counting"

    def __init__(self, step: int = 1, value: int = 0) -> None:
        super().__init__("counting camera")
        self.step, self.value = step, value
        self.seq = 0

    def _do_open(self) -> None:
        self.seq = 100

    def _do_close(self) -> None:
        pass

    def _do_grab(self, timeout_s: float) -> Frame | None:
        if timeout_s <= 0:
            raise DeviceTimeout(f"{self.description}: no frame within {timeout_s} s")
        self.seq += self.step
        pixels = np.full((4, 6), self.value or self.seq % 1024, np.uint16)
        return Frame(pixels=pixels, seq=self.seq, t_ns=time.monotonic_ns(), bits=10)


class Board:
    """The contact behind the relay, as a bench emulator would expose it."""

    def __init__(self) -> None:
        self.is_on = False

    def set(self, on: bool) -> None:
        self.is_on = on


class BoardRelay(LaserRelay):
    """A relay driver for :class:`Board`, with readback."""

    supports_readback = True

    def __init__(self, board: Board, ignore_off: bool = False) -> None:
        super().__init__(description="bench board")
        self.board, self.ignore_off = board, ignore_off

    def _do_switch(self, on: bool) -> None:
        if on or not self.ignore_off:
            self.board.is_on = on

    def _do_read_state(self) -> bool:
        return self.board.is_on

    def _do_close(self) -> None:
        pass


class WriteOnlyBoardRelay(BoardRelay):
    """The same board driven without readback (like an LCUS board): nothing can tell a lost off."""

    supports_readback = False


def test_a_minimal_camera_driver_passes_the_camera_contract() -> None:
    check_camera_contract(CountingCamera)
    assert list(CAMERA_CHECKS) == ["lifecycle", "frames", "bad_settings_refused", "frames_after_reopen",
                                 "frame_format"]


def test_camera_checks_catch_seq_going_backwards_and_pixels_beyond_their_bits() -> None:
    with pytest.raises(AssertionError, match=r"seq not strictly rising: \[99, 98, 97, 96, 95\]"):
        check_frames(lambda: CountingCamera(step=-1))
    with pytest.raises(AssertionError, match="pixel value 1500 beyond 10 bits"):
        check_frames(lambda: CountingCamera(value=1500))


class MisleadingCamera(CountingCamera):
    """Says its frames are 5x5 (or 8-bit); they come 4x6, 10-bit."""

    told = FrameFormat.of((5, 5), 10)

    def _do_frame_format(self) -> FrameFormat:
        return self.told


class WrongBitsCamera(MisleadingCamera):
    """Tells the shape right and the bits wrong."""

    told = FrameFormat.of((4, 6), 8)


def test_the_camera_contract_catches_a_frame_format_the_frames_do_not_have() -> None:
    with pytest.raises(AssertionError, match=r"frame_format\(\) said \(\(5, 5\), 10, 'uint16'\), "
                                             r"the frames came as \[\(\(4, 6\), 10, 'uint16'\)\]"):
        CAMERA_CHECKS["frame_format"](MisleadingCamera)
    with pytest.raises(AssertionError, match=r"said \(\(4, 6\), 8, 'uint8'\)"):
        CAMERA_CHECKS["frame_format"](WrongBitsCamera)


def test_a_minimal_relay_driver_passes_the_relay_contract() -> None:
    board = Board()
    check_relay_contract(RelayRig(open=lambda: BoardRelay(board), is_on=lambda: board.is_on,
                                  readback=True, force=board.set))
    assert not board.is_on
    assert len(RELAY_CHECKS) == 6


def test_relay_checks_catch_a_driver_that_does_not_switch_off() -> None:
    board = Board()
    rig = RelayRig(open=lambda: WriteOnlyBoardRelay(board, ignore_off=True), is_on=lambda: board.is_on,
                   readback=False, settle_s=0.05)
    with pytest.raises(AssertionError, match=r"the contact is ON after close\(\)"):
        RELAY_CHECKS["close_leaves_it_off"](rig)


def test_relay_checks_catch_a_driver_claiming_readback_the_board_lacks() -> None:
    board = Board()
    rig = RelayRig(open=lambda: BoardRelay(board), is_on=lambda: board.is_on, readback=False)
    with pytest.raises(AssertionError, match="readback is True, the board has no readback"):
        RELAY_CHECKS["readback_is_reported_honestly"](rig)
    assert not board.is_on  # the failed check still left the laser off
