"""SlidingWindow constructs the engine of its mode; each engine's state is its ring plus its
accumulators' sums, and nothing else."""

from __future__ import annotations

import numpy as np
import pytest

from edgedsm.errors import EstimatorError
from edgedsm.estimators import SlidingWindow
from edgedsm.estimators.streaming import ENGINES, MODES


@pytest.mark.parametrize("mode", MODES)
def test_the_mode_picks_its_engine_keyword_or_positional(mode):
    by_name = SlidingWindow((4, 5), 12, 3, mode=mode)
    positional = SlidingWindow((4, 5), 12, 3, 0.0, None, ("s1", "s2", "s3"), mode)
    assert type(by_name) is type(positional) is ENGINES[mode]
    assert isinstance(by_name, SlidingWindow) and by_name.mode == mode
    direct = ENGINES[mode]((4, 5), 12, 3)
    assert direct.mode == mode and direct.estimators == ("s1", "s2", "s3")


def test_default_mode_is_sliding_and_a_wrong_mode_is_refused():
    assert type(SlidingWindow((2, 2), 4, 1)) is ENGINES["sliding"]
    with pytest.raises(EstimatorError, match="mode must be one of"):
        SlidingWindow((2, 2), 4, 1, mode="hopping")
    with pytest.raises(EstimatorError, match="mode must be one of"):
        SlidingWindow((2, 2), 4, 1, mode=["sliding"])
    with pytest.raises(EstimatorError, match="asked of the tumbling engine"):
        ENGINES["tumbling"]((2, 2), 4, 1, mode="sliding")


@pytest.mark.parametrize(("mode", "estimators", "arrays"), [
    ("sliding", ("s2",), {"ring": 10 * 8, "abs": 0, "ratio": 64, "total": 0, "total_sq": 0, "products": 0,
                          "retired": 0}),
    ("sliding", ("s3", "tau_c"), {"ring": 10 * 8, "abs": 32, "ratio": 0, "total": 32, "total_sq": 32,
                                  "products": 4 * 32, "retired": 0}),  # K = 4: lags 1, 2, 3, 4
    ("tumbling", ("s1",), {"ring": 4 * 8, "abs": 32, "ratio": 0, "total": 0, "total_sq": 0, "products": 0,
                           "edges": 0, "done_abs": 32, "done_ratio": 0, "done_total": 0, "done_total_sq": 0,
                           "done_products": 0, "done_edges": 0}),
    ("exponential", ("s1", "s3"), {"ring": 3 * 8, "mean": 64, "m2": 64, "abs": 64, "ratio": 0}),
])
def test_the_state_is_the_ring_and_the_accumulators_sums(mode, estimators, arrays):
    """8 pixels, 8-bit data, N = 10, m = 3, K = 4: the bytes of every array by name."""
    engine = SlidingWindow((2, 4), 10, 3, bits=8, estimators=estimators, mode=mode, max_lag=4)
    assert engine.tau_lags.tolist() == [1, 2, 3, 4]
    assert engine.array_bytes() == arrays
    assert engine.bytes_per_pixel == sum(arrays.values()) / 8


@pytest.mark.parametrize("mode", MODES)
def test_reset_also_forgets_the_accumulators_progress(mode):
    frames = np.random.default_rng(5).integers(0, 256, (23, 3, 3), dtype=np.uint8)
    estimators = ("s1", "s2", "s3") + (() if mode == "exponential" else ("tau_c",))
    engine = SlidingWindow((3, 3), 6, 2, bits=8, estimators=estimators, mode=mode, max_lag=2)
    for frame in frames[:13]:
        engine.push(frame)
    engine.reset()
    fresh = SlidingWindow((3, 3), 6, 2, bits=8, estimators=estimators, mode=mode, max_lag=2)
    for frame in frames[13:]:
        engine.push(frame)
        fresh.push(frame)
    for name, values in fresh.maps().items():
        np.testing.assert_array_equal(engine.maps()[name], values)
    assert engine._snapshot()["weights"] == fresh._snapshot()["weights"]


@pytest.mark.parametrize("mode", MODES)
def test_a_reset_with_the_bits_given_zeroes_the_same_arrays_and_fault_in_needs_an_empty_window(mode):
    """The daemon writes its engine's pages before frames flow (``fault_in``) and keeps them
    across restarts: a reset zeroes the arrays in place instead of allocating fresh ones."""
    frames = np.random.default_rng(6).integers(0, 256, (9, 3, 3), dtype=np.uint8)
    engine = SlidingWindow((3, 3), 6, 2, bits=8, mode=mode)
    engine.fault_in()
    arrays = dict(engine._arrays)
    for frame in frames:
        engine.push(frame)
    assert any(array.any() for array in arrays.values())
    with pytest.raises(EstimatorError, match=r"erase the 9 frames pushed: reset\(\) first"):
        engine.fault_in()
    engine.reset()
    # the same array objects (a tumbling engine swaps them between its block's names)
    assert sorted(map(id, engine._arrays.values())) == sorted(map(id, arrays.values()))
    assert not any(array.any() for array in engine._arrays.values())
