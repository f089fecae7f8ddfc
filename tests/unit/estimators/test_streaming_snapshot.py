"""Engine snapshots (issue 13): maps computed from a copy of the sums, on another thread, are
bit-identical to ``maps()`` at the moment of the snapshot, and later pushes do not change them."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from edgedsm.errors import EstimatorError
from edgedsm.estimators import SlidingWindow
from edgedsm.estimators.snapshot import MapBuffers, maps_from
from tests.unit.estimators.test_streaming import KERNELS, MODES, feed


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("bits", [8, 12])
def test_snapshot_maps_bit_identical_and_frozen(kernel: str, mode: str, bits: int) -> None:
    rng = np.random.default_rng(13)
    dtype = np.uint8 if bits <= 8 else np.uint16
    # 300x300 is above PARALLEL_MIN_PIXELS: the engine's maps run parallel, the snapshot's serial
    frames = rng.integers(0, 1 << bits, size=(40, 300, 300), dtype=dtype)
    engine = feed(SlidingWindow((300, 300), window=16, lag=3, q=1.5, bits=bits, mode=mode, kernel=kernel), frames[:30])
    expected = engine.maps()
    snapshot = engine.snapshot()
    feed(engine, frames[30:])  # the engine moves on; the snapshot must not
    result: dict[str, dict[str, np.ndarray]] = {}
    thread = threading.Thread(target=lambda: result.update(maps=maps_from(snapshot)))
    thread.start()
    thread.join()
    maps = result["maps"]
    assert sorted(maps) == ["s1", "s2", "s3"]
    for name, values in expected.items():
        assert maps[name].shape == (300, 300)
        assert np.array_equal(maps[name].view(np.int64), values.view(np.int64)), name
    assert not np.array_equal(engine.maps()["s1"], maps["s1"])  # the engine did move on
    assert snapshot.frames_seen == 30


def test_snapshot_only_requested_estimators() -> None:
    frames = np.random.default_rng(1).integers(0, 256, size=(12, 8, 8), dtype=np.uint8)
    engine = feed(SlidingWindow((8, 8), window=10, lag=2, estimators=("s2",), kernel="numpy"), frames)
    snapshot = engine.snapshot()
    assert sorted(maps_from(snapshot)) == ["s2"]
    assert snapshot.nbytes == 64 * 8  # only the S2 sum is kept (int64)


def test_snapshot_before_the_window_is_full_is_refused() -> None:
    engine = SlidingWindow((4, 4), window=10, lag=2, bits=8)
    engine.push(np.zeros((4, 4), np.uint8))
    with pytest.raises(EstimatorError, match="not full yet: 1 of 10"):
        engine.snapshot()


@pytest.mark.parametrize("mode", MODES)
def test_snapshot_of_one_estimator_copies_only_its_sums(mode: str) -> None:
    frames = np.random.default_rng(2).integers(0, 256, size=(14, 9, 7), dtype=np.uint8)
    engine = feed(SlidingWindow((9, 7), window=10, lag=2, q=1.0, mode=mode, kernel="numpy"), frames)
    full = engine.maps()
    for name in ("s1", "s2", "s3"):
        maps = maps_from(engine.snapshot([name]))
        assert sorted(maps) == [name]
        assert np.array_equal(maps[name], full[name])
    assert engine.snapshot(["s2"]).nbytes == 63 * 8  # one int64 or float64 sum
    with pytest.raises(EstimatorError, match="s4"):
        engine.snapshot(["s4"])


def test_a_snapshot_into_an_older_one_reuses_its_buffers() -> None:
    frames = np.random.default_rng(4).integers(0, 256, size=(30, 20, 20), dtype=np.uint8)
    engine = feed(SlidingWindow((20, 20), window=10, lag=2, q=1.0, kernel="numpy"), frames[:12])
    first = engine.snapshot()
    feed(engine, frames[12:])
    expected = engine.maps()
    second = engine.snapshot(into=first)
    assert all(second.sums[name] is first.sums[name] for name in ("abs", "ratio", "total", "total_sq"))
    assert all(np.array_equal(maps_from(second)[name], expected[name]) for name in expected)
    # a states-only snapshot reuses what fits and leaves out the rest
    third = engine.snapshot(["s2"], into=second)
    assert third.sums["ratio"] is second.sums["ratio"] and third.sums["abs"].size == 0
    assert np.array_equal(maps_from(third)["s2"], expected["s2"])
    fourth = engine.snapshot(into=third)  # the others are fresh again
    assert fourth.sums["ratio"] is third.sums["ratio"] and np.array_equal(maps_from(fourth)["s1"], expected["s1"])


def test_map_buffers_are_reused_only_when_nobody_holds_the_maps() -> None:
    """maps_from into a MapBuffers pool: a map still held (by a sink, say) is never written over;
    once let go, the next maps land in the same memory (no page faults) and equal fresh ones."""
    rng = np.random.default_rng(5)
    frames = rng.integers(0, 256, size=(30, 40, 50), dtype=np.uint8)
    engine = feed(SlidingWindow((40, 50), window=12, lag=2, q=1.0, bits=8), frames[:20])
    pool = MapBuffers()
    held = maps_from(engine.snapshot(), pool)
    kept = {name: values.copy() for name, values in held.items()}
    feed(engine, frames[20:25])
    second = maps_from(engine.snapshot(), pool)
    assert all(not np.shares_memory(second[name], held[name]) for name in held)  # held: a new set
    assert all(np.array_equal(held[name], kept[name]) for name in held)  # and untouched
    memory = {name: values.__array_interface__["data"][0] for name, values in second.items()}
    del second
    feed(engine, frames[25:])
    third = maps_from(engine.snapshot(), pool)
    fresh = maps_from(engine.snapshot())
    assert {name: values.__array_interface__["data"][0] for name, values in third.items()} == memory
    assert all(np.array_equal(third[name], fresh[name]) for name in fresh)
    assert all(np.array_equal(held[name], kept[name]) for name in held)


def test_buffers_reserved_before_the_window_fills_are_the_ones_the_first_maps_use() -> None:
    """snapshot_buffers and MapBuffers.reserve, taken before frames flow (the daemon's start): the
    first snapshot and maps land in that memory, and equal fresh ones."""
    frames = np.random.default_rng(6).integers(0, 256, size=(14, 24, 18), dtype=np.uint8)
    engine = SlidingWindow((24, 18), window=12, lag=2, q=1.0, bits=8)
    reserved = engine.snapshot_buffers()
    assert reserved.nbytes == engine.snapshot_buffers().nbytes > 0
    assert all(not values.any() for values in reserved.sums.values())
    pool = MapBuffers()
    pool.reserve(reserved)
    memory = {name: values.__array_interface__["data"][0] for name, values in maps_from(reserved, pool).items()}
    feed(engine, frames)
    first = engine.snapshot(into=reserved)
    assert all(first.sums[name] is reserved.sums[name] for name in ("abs", "ratio", "total", "total_sq"))
    maps = maps_from(first, pool)
    assert {name: values.__array_interface__["data"][0] for name, values in maps.items()} == memory
    expected = engine.maps()
    assert all(np.array_equal(maps[name], expected[name]) for name in expected)
