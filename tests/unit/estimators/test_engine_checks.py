"""The streaming engine's boundary checks (edgedsm/estimators/engine_checks.py): each bad argument
or frame is refused with its name, a good one passes unchanged, and the engine runs them."""

from __future__ import annotations

import numpy as np
import pytest

from edgedsm.errors import EstimatorError, FrameError
from edgedsm.estimators import SlidingWindow, registry
from edgedsm.estimators.engine_checks import (
    BANDS,
    check_estimators,
    check_frame,
    check_int,
    check_maps,
    check_q,
    check_shape,
    estimator_names,
)


def test_integers_shapes_and_q() -> None:
    assert check_int("lag m", np.int64(3), 1, 5) == 3 and type(check_int("n", np.int32(2), 1, 5)) is int
    for bad, match in ((True, "integer"), (2.0, "integer"), (0, r"\[1, 5\]"), (6, r"\[1, 5\]")):
        with pytest.raises(EstimatorError, match=match):
            check_int("lag m", bad, 1, 5)
    assert check_shape([4, 7]) == (4, 7)
    for bad in (5, (1, 2, 3), (0, 4)):
        with pytest.raises(EstimatorError):
            check_shape(bad)
    assert check_q(np.float32(1.5)) == 1.5 and check_q(0) == 0.0
    for bad in (-1.0, float("nan"), float("inf"), "1", True):
        with pytest.raises(EstimatorError, match="q must be"):
            check_q(bad)


def test_the_maps_asked_for_against_the_registry() -> None:
    assert estimator_names() == (*registry.names(streams=True), BANDS)
    assert check_estimators(("s3", "s1")) == ("s1", "s3")  # the engine's order
    assert check_estimators("tau_c") == ("tau_c",)
    for bad in ((), ("s4",), ("skewness",)):  # a batch-only map does not stream
        with pytest.raises(EstimatorError, match="non-empty subset"):
            check_estimators(bad)
    check_maps(("s1", "gd"), "sliding", 1.0, 64)
    with pytest.raises(EstimatorError, match=r"'gd'.*exponential"):
        check_maps(("gd",), "exponential", 1.0, 64)
    zero_q = [name for name in registry.names(streams=True) if registry.get(name).needs_q_zero]
    with pytest.raises(EstimatorError, match=r"q=0, got q=1\.0"):
        check_maps(zero_q, "sliding", 1.0, 64)
    check_maps(zero_q, "sliding", 0.0, 64)
    largest = 2 ** 31  # C(N, 2)·65535 must stay below 2^63: N about 1.68e7
    with pytest.raises(EstimatorError, match="overflows its int64 sum"):
        check_maps(("gd",), "sliding", 1.0, largest)
    check_maps(("s1",), "sliding", 1.0, largest)


def test_frames() -> None:
    frame = np.zeros((3, 4), np.uint8)
    assert check_frame(frame, (3, 4), None) == 8 and check_frame(frame.astype(np.uint16), (3, 4), None) == 16
    assert check_frame(np.full((3, 4), 4095, np.uint16), (3, 4), 12) == 12
    bad = [([[0]], None, "numpy array"), (np.zeros((4, 3), np.uint8), None, "does not match"),
           (np.zeros((3, 4), np.int16), None, "not uint8 or uint16"),
           (np.zeros((3, 4), np.uint16), 8, "is not uint8"),
           (np.zeros((4, 8), np.uint8)[:3, ::2], None, "C-contiguous"),
           (np.full((3, 4), 4096, np.uint16), 12, "above the 12-bit range")]
    for value, bits, match in bad:
        with pytest.raises(FrameError, match=match):
            check_frame(value, (3, 4), bits)


def test_the_engine_runs_them() -> None:
    with pytest.raises(EstimatorError, match="q must be"):
        SlidingWindow((4, 4), window=8, lag=1, q=-1.0)
    engine = SlidingWindow((4, 4), window=8, lag=1, bits=10)
    with pytest.raises(FrameError, match="above the 10-bit range"):
        engine.push(np.full((4, 4), 1024, np.uint16))
    assert engine.frames_seen == 0  # a refused frame changes nothing
