"""Prefetched: a reader's frames decoded one frame ahead on a thread, in order, errors raised at
their frame, the thread stopped when the caller stops."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

from edgedsm.frameio import ReaderError, open_frames
from edgedsm.frameio.prefetch import Prefetched


def numbered(count: int, log: list[int], fail_at: int | None = None) -> Iterator[np.ndarray]:
    """Frames whose pixels are their index; ``log`` the indices made; a ReaderError at ``fail_at``."""
    try:
        for index in range(count):
            if index == fail_at:
                raise ReaderError(f"frame {index} is damaged")
            log.append(index)
            yield np.full((4, 5), index, np.uint8)
    finally:
        log.append(-1)  # closed


def test_frames_come_in_order_and_unchanged(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    frames = rng.integers(0, 256, (7, 12, 9), dtype=np.uint8)
    for index, frame in enumerate(frames):
        cv2.imwrite(str(tmp_path / f"img_{index}.png"), frame)
    with open_frames(tmp_path) as reader, Prefetched(reader.frames(), depth=2) as ahead:
        got = list(ahead)
    assert len(got) == 7
    assert all(np.array_equal(a, b) for a, b in zip(got, frames, strict=True))


def test_reads_ahead_by_depth_only() -> None:
    log: list[int] = []
    ahead = Prefetched(numbered(10, log), depth=2)
    first = next(ahead)
    deadline = time.monotonic() + 5
    while len(log) < 4 and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(0.1)
    assert int(first[0, 0]) == 0
    assert log == [0, 1, 2, 3]  # the one taken, two queued, one in the thread's hands: no more decoded
    ahead.close()
    assert log[-1] == -1  # the iterator was closed on its thread


def test_an_error_is_raised_at_its_frame() -> None:
    log: list[int] = []
    got = []
    with pytest.raises(ReaderError, match="frame 3 is damaged"), Prefetched(numbered(6, log, fail_at=3)) as ahead:
        for frame in ahead:
            got.append(int(frame[0, 0]))
    assert got == [0, 1, 2]


def test_stopping_early_ends_the_thread() -> None:
    log: list[int] = []
    before = threading.active_count()
    with Prefetched(numbered(1000, log)) as ahead:
        for frame in ahead:
            if frame[0, 0] == 4:
                break
    assert threading.active_count() == before
    assert log[-1] == -1 and max(log) <= 6
    assert list(ahead) == []  # closed: nothing more


def test_depth_must_be_positive() -> None:
    with pytest.raises(ValueError, match="depth"):
        Prefetched(iter([]), depth=0)
