"""A region's box, statistics and percentiles (edgedsm/estimators/region_box.py)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from edgedsm.errors import EstimatorError
from edgedsm.estimators.region_box import RegionBox, bounding_box, percentiles, region_mean, region_stats


def test_percentiles_of_large_regions_from_a_stride():
    rng = np.random.default_rng(2)
    values = rng.exponential(size=(1024, 1024))
    mask = np.ones_like(values, bool)
    stats = region_stats(values, mask)
    exact = np.percentile(values, [5, 50, 95])
    assert stats.pixels == 1024 * 1024 and stats.mean == pytest.approx(values.mean(), rel=1e-12)
    assert [stats.p05, stats.median, stats.p95] == pytest.approx(exact, rel=0.02)


def test_region_box_reads_the_box_only_with_the_same_statistics() -> None:
    rng = np.random.default_rng(5)
    values = rng.random((60, 80))
    mask = np.zeros((60, 80), bool)
    mask[10:20, 30:35] = True
    mask[25, 60] = True
    box = RegionBox.of(mask)
    assert (box.rows, box.cols) == (slice(10, 26), slice(30, 61))
    assert box.mask.shape == (16, 31) and box.pixels == 51
    assert box.stats(values) == region_stats(values, mask)
    assert box.mean(values) == region_mean(values, mask)
    # in a map of the union box only (estimator.area = "regions")
    other = np.zeros((60, 80), bool)
    other[5, 40] = True
    rows, cols = bounding_box([mask, other])
    assert (rows, cols) == (slice(5, 26), slice(30, 61))
    assert box.shifted(rows, cols).stats(values[rows, cols]) == region_stats(values, mask)
    with pytest.raises(EstimatorError, match="empty"):
        RegionBox.of(np.zeros((3, 3), bool))


@pytest.mark.parametrize("size", [1, 2, 3, 7, 20, 21, 101, 1000, 4097, 1 << 18])
def test_percentiles_from_the_sorted_sample_equal_numpy_s(size: int) -> None:
    """Read off the sorted sample: the same numbers, bit for bit, as np.percentile on the
    unsorted sample, ties, wide ranges and NaN included."""
    rng = np.random.default_rng(size)
    wide = rng.standard_normal(size) * 10.0 ** rng.integers(-300, 300, size)
    with_nan = rng.random(size)
    with_nan[size // 2] = np.nan
    for sample in (rng.random(size), rng.integers(0, 5, size).astype(float), wide, -rng.random(size) * 1e-3,
                   with_nan):
        expected = np.percentile(sample, [5, 50, 95])
        got = percentiles(sample)
        assert np.array_equal(got, expected, equal_nan=True), (got, expected)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(allow_nan=False, allow_infinity=False, width=64), min_size=1, max_size=300))
def test_percentiles_equal_numpy_s_for_any_sample(values: list[float]) -> None:
    sample = np.asarray(values)
    ordered = np.sort(sample)
    with np.errstate(over="ignore"):
        span = ordered[-1] - ordered[0]
    if np.isfinite(span):
        assert np.array_equal(percentiles(sample), np.percentile(sample, [5, 50, 95]))
        return
    # a span beyond the float range, where numpy's own interpolation overflows: finite, between
    # the two order statistics around each percentile, and ordered
    got = percentiles(sample)
    virtual = (sample.size - 1) * np.array([0.05, 0.5, 0.95])
    for value, at in zip(got, virtual, strict=True):
        assert ordered[int(np.floor(at))] <= value <= ordered[int(np.ceil(at))]
    assert got[0] <= got[1] <= got[2]


def test_percentiles_of_values_more_than_the_float_range_apart() -> None:
    p05, median, p95 = percentiles(np.array([3.4250046158761823e307, -1.4551926732746976e308]))
    assert median == pytest.approx((3.4250046158761823e307 - 1.4551926732746976e308) / 2, rel=1e-15)
    assert p05 == pytest.approx(-1.4551926732746976e308 * 0.95 + 3.4250046158761823e307 * 0.05, rel=1e-15)
    assert p95 == pytest.approx(-1.4551926732746976e308 * 0.05 + 3.4250046158761823e307 * 0.95, rel=1e-15)
