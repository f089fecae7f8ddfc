from __future__ import annotations

import numpy as np
import pytest

from edgedsm.analysis import contrast, histogram, region_mean, region_means, region_stats
from edgedsm.errors import EstimatorError


def test_contrast_beta_is_paper_definition():
    values = np.array([[4.0, 4.0], [1.0, 1.0]])
    active = np.array([[True, True], [False, False]])
    assert contrast(values, active, ~active) == pytest.approx((4 - 1) / 4)
    assert contrast(np.zeros((2, 2)), active, ~active) == 0.0


def test_region_stats_and_means():
    values = np.arange(100, dtype=float).reshape(10, 10)
    mask = np.zeros((10, 10), bool)
    mask[:5] = True
    stats = region_stats(values, mask)
    assert stats.pixels == 50 and stats.mean == pytest.approx(24.5)
    assert stats.median == pytest.approx(24.5) and stats.p05 == pytest.approx(2.45)
    assert region_means(values, {"top": mask, "bottom": ~mask, "none": np.zeros_like(mask)}) == {
        "top": pytest.approx(24.5), "bottom": pytest.approx(74.5)}


def test_empty_or_mismatched_region_is_an_error():
    with pytest.raises(EstimatorError, match="empty"):
        region_mean(np.ones((2, 2)), np.zeros((2, 2), bool))
    with pytest.raises(EstimatorError, match="differ"):
        region_mean(np.ones((2, 2)), np.ones((3, 3), bool))
    with pytest.raises(EstimatorError, match="boolean"):
        region_mean(np.ones((2, 2)), np.ones((2, 2)))


def test_histogram_is_a_density():
    values = np.random.default_rng(0).normal(size=(100, 100))
    density, edges = histogram(values, bins=50, value_range=(-5, 5))
    assert (density * np.diff(edges)).sum() == pytest.approx(1.0)
    mask = values > 0
    density, edges = histogram(values, bins=10, mask=mask)
    assert edges[0] >= 0
