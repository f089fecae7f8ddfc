"""Property tests: degenerate pixels (dark, saturated, constant, and a mix with live pixels) give
defined values, never NaN or inf, for every descriptor of the registry and the THSP moments."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from edgedsm.estimators.descriptors import DESCRIPTORS, compute
from edgedsm.estimators.thsp import avd, coom, inertia_moment, thsp


@st.composite
def stacks(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    """(stack, constant mask): random frames where some pixels are held at 0, at full scale or at
    a fixed level for the whole stack."""
    dtype = draw(st.sampled_from([np.uint8, np.uint16]))
    top = int(np.iinfo(dtype).max)
    n = draw(st.integers(2, 12))
    h, w = draw(st.integers(1, 4)), draw(st.integers(1, 4))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    stack = rng.integers(0, top + 1, (n, h, w)).astype(dtype)
    kinds = rng.integers(0, 4, (h, w))  # 0 live, 1 dark, 2 saturated, 3 constant
    stack[:, kinds == 1] = 0
    stack[:, kinds == 2] = top
    level = draw(st.integers(0, top))
    stack[:, kinds == 3] = level
    return stack, kinds > 0


@settings(max_examples=60, deadline=None)
@given(stacks())
def test_every_descriptor_is_finite_and_zero_on_constant_pixels(case: tuple[np.ndarray, np.ndarray]) -> None:
    stack, constant = case
    for name in DESCRIPTORS:
        result = compute(name, stack, lag=1, threshold=0.0)
        assert np.isfinite(result).all(), name
        # every descriptor is 0 on a constant pixel by definition (module doc of descriptors)
        assert (result[constant] == 0).all(), name


@settings(max_examples=30, deadline=None)
@given(st.sampled_from([0, 17, 255]), st.integers(2, 10), st.integers(1, 5))
def test_a_constant_line_has_zero_com_moments(level: int, n: int, width: int) -> None:
    stack = np.full((n, 2, width), level, np.uint8)
    com = coom(thsp(stack, row=1))
    assert com[level, level] == width * (n - 1) and com.sum() == width * (n - 1)
    assert inertia_moment(com) == 0 and avd(com) == 0
