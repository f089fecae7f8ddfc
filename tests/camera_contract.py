"""The camera contract, as checks every driver must pass (real and simulated alike).

A test module provides a factory ``make() -> Camera`` (unopened) and calls ``run_contract``;
or calls the individual checks. Keep checks driver-agnostic.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable

import numpy as np
import pytest

from edgedsm.devices.camera import Camera
from edgedsm.errors import DeviceError

Factory = Callable[[], Camera]


def check_lifecycle(make: Factory) -> None:
    camera = make()
    assert not camera.is_open
    with pytest.raises(DeviceError, match="not open"):
        next(camera.frames(1))
    with camera:
        assert camera.is_open
    assert not camera.is_open
    camera.close()  # closing twice is harmless


def check_frames(make: Factory, count: int = 5) -> None:
    with make() as camera:
        frames = list(camera.frames(count))
    assert len(frames) == count
    seqs = [f.seq for f in frames]
    assert seqs == sorted(seqs) and len(set(seqs)) == count
    times = [f.t_ns for f in frames]
    assert all(b >= a for a, b in itertools.pairwise(times))
    for frame in frames:
        assert frame.pixels.ndim == 2
        assert frame.pixels.dtype in (np.uint8, np.uint16)
        assert 1 <= frame.bits <= 16
        assert int(frame.pixels.max()) < 2**frame.bits
    assert camera.stats["delivered"] == count


def check_bad_settings_refused(make: Factory) -> None:
    with make() as camera:
        with pytest.raises(DeviceError, match="exposure"):
            camera.set_exposure(-1)
        with pytest.raises(DeviceError, match="frame interval"):
            camera.set_frame_interval(0)
        with pytest.raises(DeviceError, match="pixel format"):
            camera.set_pixel_format("RGB8")


def check_frames_after_reopen(make: Factory) -> None:
    camera = make()
    with camera:
        first = list(camera.frames(2))
    with camera:
        second = list(camera.frames(2))
    assert len(first) == len(second) == 2


def run_contract(make: Factory) -> None:
    check_lifecycle(make)
    check_frames(make)
    check_bad_settings_refused(make)
    check_frames_after_reopen(make)
