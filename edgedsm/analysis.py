"""Reducing activity maps: region means, the contrast β of the paper, histograms.

Pure functions on float maps and boolean masks (same shape); no I/O. A region's box and
statistics are the estimators' (:mod:`edgedsm.estimators.region_box`), named here too for the
callers above the measurement layer that reduce maps (the dashboard, preflight, the lab).
"""

from __future__ import annotations

import numpy as np

from edgedsm.errors import EstimatorError
from edgedsm.estimators.region_box import PERCENTILE_SAMPLES as PERCENTILE_SAMPLES
from edgedsm.estimators.region_box import RegionBox as RegionBox
from edgedsm.estimators.region_box import RegionStats as RegionStats
from edgedsm.estimators.region_box import bounding_box as bounding_box
from edgedsm.estimators.region_box import checked, region_mean
from edgedsm.estimators.region_box import percentiles as percentiles
from edgedsm.estimators.region_box import region_stats as region_stats


def region_means(values: np.ndarray, masks: dict[str, np.ndarray]) -> dict[str, float]:
    """Mean of ``values`` in each named mask (empty masks are skipped)."""
    return {name: region_mean(values, mask) for name, mask in masks.items() if mask.any()}


def contrast(values: np.ndarray, active: np.ndarray, background: np.ndarray) -> float:
    """β = (S_l - S_b)/S_l with S_l, S_b the means over the active and background areas.

    Paper §2C. S_l = 0 (no activity at all) gives β = 0.
    """
    s_l = region_mean(values, active)
    s_b = region_mean(values, background)
    return 0.0 if s_l == 0 else (s_l - s_b) / s_l


def histogram(values: np.ndarray, bins: int = 100, value_range: tuple[float, float] | None = None,
              mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Probability density of the map entries (optionally inside ``mask``): (density, edges)."""
    if bins < 1:
        raise EstimatorError("bins must be >= 1")
    data = np.asarray(values, np.float64)
    if mask is not None:
        data, mask = checked(data, mask)
        data = data[mask]
    if data.size == 0:
        raise EstimatorError("no values to histogram")
    return np.histogram(data, bins=bins, range=value_range, density=True)
