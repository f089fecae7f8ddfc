"""Property-based tests: the streaming engine against the batch reference (and its own
exponential definition) on random streams, parameters and bit depths."""

from __future__ import annotations

from fractions import Fraction

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from test_streaming import (
    KERNELS,
    assert_matches_batch,
    assert_matches_exponential,
    assert_snapshots_equal,
    exact_s2,
)

from edgedsm.estimators import SlidingWindow

PROPERTY = settings(max_examples=60, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@st.composite
def streams(draw, max_window: int = 12, max_length: int = 4):
    """(frames, window, lag, q, bits): a random stream that fills its window at least once."""
    window = draw(st.integers(2, max_window))
    lag = draw(st.integers(1, window - 1))
    bits = draw(st.sampled_from([1, 5, 8, 10, 14, 16]))
    q = draw(st.sampled_from([0.0, 0.5, 1.0, 3.0, 0.1]))
    length = draw(st.integers(window, max_length * window))
    shape = (draw(st.integers(1, 3)), draw(st.integers(1, 3)))
    top = 2**bits - 1
    # boundary values often: 0 and full scale are where the degenerate cases live
    elements = st.one_of(st.sampled_from([0, top]), st.integers(0, top))
    frames = draw(arrays(np.uint8 if bits <= 8 else np.uint16, (length, *shape),
                         elements=elements))
    return frames, window, lag, q, bits


@PROPERTY
@given(streams(), st.sampled_from(KERNELS), st.sampled_from(["sliding", "tumbling"]))
def test_window_modes_equal_the_batch_reference(stream, kernel, mode):
    frames, window, lag, q, bits = stream
    engine = SlidingWindow(frames.shape[1:], window, lag, q=q, bits=bits, mode=mode,
                           kernel=kernel)
    for frame in frames:
        engine.push(frame)
    assert_matches_batch(engine, frames)


@PROPERTY
@given(streams(max_window=8, max_length=2), st.sampled_from(KERNELS))
def test_s2_within_the_stated_bound_of_the_exact_value(stream, kernel):
    frames, window, lag, q, bits = stream
    engine = SlidingWindow(frames.shape[1:], window, lag, q=q, bits=bits, kernel=kernel,
                           estimators=("s2",))
    for frame in frames:
        engine.push(frame)
    exact = exact_s2(frames[-window:], lag, q)
    got = engine.maps()["s2"]
    for value, true in zip(got.ravel(), exact.ravel(), strict=True):
        assert abs(Fraction(float(value)) - true) <= Fraction(engine.s2_bound)


@PROPERTY
@given(streams(max_window=8, max_length=3), st.sampled_from(KERNELS))
def test_exponential_mode_within_its_bounds(stream, kernel):
    frames, window, lag, q, bits = stream
    engine = SlidingWindow(frames.shape[1:], window, lag, q=q, bits=bits, kernel=kernel,
                           mode="exponential")
    for frame in frames:
        engine.push(frame)
    assert_matches_exponential(engine, frames)


@PROPERTY
@given(streams(), st.sampled_from(["sliding", "tumbling", "exponential"]))
def test_kernels_agree_bit_for_bit(stream, mode):
    frames, window, lag, q, bits = stream
    engines = [SlidingWindow(frames.shape[1:], window, lag, q=q, bits=bits, mode=mode,
                             kernel=kernel) for kernel in KERNELS]
    for frame in frames:
        for engine in engines:
            engine.push(frame)
    for other in engines[1:]:
        assert_snapshots_equal(engines[0]._snapshot(), other._snapshot())
