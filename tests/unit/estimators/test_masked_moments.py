"""The masked region pass (edgedsm/estimators/masked_moments.py), compiled and in NumPy."""

from __future__ import annotations

import numpy as np
import pytest

from edgedsm.estimators.masked_moments import masked_moments, masked_moments_numpy


@pytest.mark.parametrize("kernel", ["numba", "numpy"])
def test_region_moments_match_numpy_on_views_without_copies(kernel: str) -> None:
    moments = masked_moments_numpy if kernel == "numpy" else masked_moments
    rng = np.random.default_rng(9)
    values = rng.exponential(size=(700, 900)) * 1e3 + 1e6  # a large offset: naive sums would lose digits
    mask = rng.random((700, 900)) < 0.7
    rows, cols = slice(50, 650), slice(100, 800)
    count, mean, std, sample = moments(values[rows, cols], mask[rows, cols], 1000)
    selected = values[rows, cols][mask[rows, cols]]
    assert count == selected.size
    assert mean == pytest.approx(float(np.mean(selected.astype(np.longdouble))), rel=1e-15)
    exact_std = float(np.sqrt(np.mean((selected.astype(np.longdouble) - selected.astype(np.longdouble).mean()) ** 2)))
    assert std == pytest.approx(exact_std, rel=1e-12)
    stride = -(-selected.size // 1000)
    assert np.array_equal(sample, selected[::stride]) and sample.size <= 1000
