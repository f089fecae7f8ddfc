"""Streams of a million frames with adversarial pixels: the maps after them equal the batch
reference on the current window within the stated bounds (no drift, no overflow)."""

from __future__ import annotations

import numpy as np
import pytest
from test_streaming import (
    assert_matches_batch,
    assert_snapshots_equal,
    exponential_reference,
)

from edgedsm.estimators import SlidingWindow

pytestmark = pytest.mark.slow

COUNT = 1_000_000
WINDOW, LAG = 200, 10
FLICKER_OLD, FLICKER_NEW = 12_345, COUNT - 50  # one flicker long gone, one inside the window
BURST = slice(400_000, 400_500)  # a constant pixel that was busy once


def adversarial_stream(count: int, bits: int) -> np.ndarray:
    """(count, 2, 4) frames; pixel k of each frame follows pattern k below."""
    top = 2**bits - 1
    rng = np.random.default_rng(bits)
    i = np.arange(count)
    flat = np.empty((count, 8), np.uint8 if bits <= 8 else np.uint16)
    flat[:, 0] = np.where(i % 2, top, 0)  # 0/max alternation
    flat[:, 1] = 0  # dark: every S2 pair is 0/0 when q = 0
    flat[:, 2] = top  # saturated
    flat[:, 3] = 0  # single flickers
    flat[[FLICKER_OLD, FLICKER_NEW], 3] = top
    flat[:, 4] = rng.integers(0, top + 1, count)  # noise
    flat[:, 5] = np.where(i % 3 == 2, 0, top)  # max, max, 0
    flat[:, 6] = top // 2  # constant ...
    flat[BURST, 6] = rng.integers(0, top + 1, BURST.stop - BURST.start)  # ... after a burst
    flat[:, 7] = i % (top + 1)  # saw-tooth with a full-scale drop
    return flat.reshape(count, 2, 4)


def run(engine: SlidingWindow, frames: np.ndarray) -> SlidingWindow:
    for frame in frames:
        engine.push(frame)
    return engine


@pytest.mark.parametrize("bits", [8, 16])
def test_sliding_million_frames_equals_batch(bits):
    frames = adversarial_stream(COUNT, bits)
    engine = run(SlidingWindow((2, 4), WINDOW, LAG, q=0.0), frames)
    assert engine.frames_seen == COUNT
    assert_matches_batch(engine, frames)
    maps = engine.maps()
    assert all(np.isfinite(values).all() for values in maps.values())
    # the busy stretch of pixel 6 left no trace: σ = 0 and S3 = 0 exactly
    assert engine.sigma()[1, 2] == 0.0 and maps["s3"][1, 2] == 0.0 and maps["s1"][1, 2] == 0.0
    # 0/max alternation at an even lag: every pair is equal
    assert maps["s1"][0, 0] == 0.0 and maps["s2"][0, 0] == 0.0
    # the sums after a million updates are those recomputed from the window
    before = engine._snapshot()
    engine.resync()
    assert_snapshots_equal(before, engine._snapshot())


def test_tumbling_million_frames_equals_batch():
    frames = adversarial_stream(COUNT + 37, 8)
    engine = run(SlidingWindow((2, 4), WINDOW, LAG, q=1.0, mode="tumbling"), frames)
    assert engine.blocks_completed == COUNT // WINDOW
    assert_matches_batch(engine, frames)


def test_exponential_million_frames_within_bound():
    frames = adversarial_stream(COUNT, 8)
    engine = run(SlidingWindow((2, 4), WINDOW, LAG, q=0.0, mode="exponential"), frames)
    # λ^12000 = e^-60: older frames weigh nothing a float64 could hold
    ref = exponential_reference(frames[-12_000:], WINDOW, LAG, 0.0)
    u, top = 2.0**-53, 255.0
    maps = engine.maps()
    assert np.max(np.abs(maps["s1"] - ref["s1"])) <= 8 * WINDOW * u * top
    assert np.max(np.abs(maps["s2"] - ref["s2"])) <= 8 * WINDOW * u
    assert np.max(np.abs(engine.sigma() ** 2 - ref["var"])) <= 16 * WINDOW * u * top**2
    assert all(np.isfinite(values).all() for values in maps.values())
    assert maps["s3"][0, 1] == 0.0 and maps["s3"][0, 2] == 0.0  # dark and saturated: σ = 0
