"""A map reduced over one region: the region's box (:class:`RegionBox`), its statistics
(:class:`RegionStats`: count, mean, deviation, 5/50/95 % percentiles) and the percentiles read off
a sorted sample. The estimators' region pass (:mod:`edgedsm.estimators.region_stats`), the
measurement core and :mod:`edgedsm.analysis` all reduce with these.

Pure functions on float maps and boolean masks (same shape); no I/O. Units: the map's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from edgedsm.errors import EstimatorError
from edgedsm.estimators.masked_moments import masked_moments


@dataclass(frozen=True)
class RegionStats:
    """Statistics of one map over one region (units of the map)."""

    pixels: int
    mean: float
    std: float
    p05: float
    median: float
    p95: float

    def as_dict(self) -> dict[str, float]:
        return {"pixels": self.pixels, "mean": self.mean, "std": self.std, "p05": self.p05,
                "median": self.median, "p95": self.p95}


def checked(values: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``values`` and ``mask`` as arrays, the mask boolean and of the map's shape (else an
    EstimatorError naming which)."""
    values = np.asarray(values)
    mask = np.asarray(mask)
    if mask.dtype != bool:
        raise EstimatorError(f"mask must be boolean, got {mask.dtype}")
    if values.shape != mask.shape:
        raise EstimatorError(f"map shape {values.shape} and mask shape {mask.shape} differ")
    return values, mask


def region_mean(values: np.ndarray, mask: np.ndarray) -> float:
    """Mean of ``values`` over ``mask``; an empty mask is an error, not NaN."""
    values, mask = checked(values, mask)
    count = int(mask.sum())
    if count == 0:
        raise EstimatorError("region is empty")
    return float(values[mask].mean(dtype=np.float64))


#: Percentiles are taken from at most this many evenly strided pixels of a region.
PERCENTILE_SAMPLES = 1 << 18


#: The percentiles of RegionStats (5, 50, 95 %) as fractions, as np.percentile forms them.
_QUANTILES = np.true_divide(np.array([5, 50, 95]), 100)


def percentiles(sample: np.ndarray) -> tuple[float, float, float]:
    """The 5, 50 and 95 % percentiles of ``sample``, equal to ``np.percentile`` (linear
    interpolation; tested): the sample sorted once (numpy's vectorised sort), then each
    percentile read off at its virtual index (n - 1)·q and interpolated with numpy's own
    formula. np.percentile partitions and copies the sample, sorted or not, and the evaluator
    thread takes six per stats message (the figures: docs/bench-design.md)."""
    ordered = np.sort(np.asarray(sample, dtype=np.float64).ravel())
    if ordered.size == 0 or np.isnan(ordered[-1]):  # numpy's rules for the empty and the NaN cases
        p05, median, p95 = np.percentile(ordered, [5, 50, 95])
        return float(p05), float(median), float(p95)
    virtual = (ordered.size - 1) * _QUANTILES
    below = np.floor(virtual)
    gamma = virtual - below
    lower = below.astype(np.intp)
    low, high = ordered[lower], ordered[np.minimum(lower + 1, ordered.size - 1)]
    with np.errstate(over="ignore"):
        step = high - low
    if np.isinf(step).any() and np.isfinite(ordered[[0, -1]]).all():
        # two finite values more than the float range apart (numpy's formula overflows there and
        # reads +-inf): the step in halves, each within range, and so is every point between them
        half = high / 2 - low / 2
        values = np.where(gamma >= 0.5, high - half * (1 - gamma) - half * (1 - gamma),
                          low + half * gamma + half * gamma)
    else:  # numpy's _lerp: from the nearer end, so that gamma = 0 and 1 give the values exactly
        values = np.where(gamma >= 0.5, high - step * (1 - gamma), low + step * gamma)
    return float(values[0]), float(values[1]), float(values[2])


def region_stats(values: np.ndarray, mask: np.ndarray) -> RegionStats:
    """Mean and standard deviation (all pixels) and 5/50/95 % percentiles over ``mask``.

    Percentiles of regions larger than ``PERCENTILE_SAMPLES`` pixels come from an even stride
    through the region, which keeps a 2048² map's statistics at a few ms (a full partition per
    percentile costs ~50 ms); activity maps vary on the speckle scale, far below the stride.
    Mean and deviation come from compensated sums without copying the region
    (:mod:`edgedsm.estimators.masked_moments`; with numba, the GIL is released meanwhile).
    """
    values, mask = checked(values, mask)
    if values.ndim != 2:
        values, mask = values.reshape(1, -1), mask.reshape(1, -1)
    count, mean, std, sample = masked_moments(values, mask, PERCENTILE_SAMPLES)
    if count == 0:
        raise EstimatorError("region is empty")
    return RegionStats(count, mean, std, *percentiles(sample))


@dataclass(frozen=True)
class RegionBox:
    """A region as its bounding box and the mask inside it: statistics read the box only, so
    their cost follows the region's size, not the frame's (same values, same order)."""

    rows: slice
    cols: slice
    mask: np.ndarray  # boolean, the box's shape

    @classmethod
    def of(cls, mask: np.ndarray) -> RegionBox:
        """The smallest box around ``mask`` (an empty mask is an error)."""
        rows, cols = bounding_box([mask])
        return cls(rows, cols, np.ascontiguousarray(mask[rows, cols]))

    def shifted(self, rows: slice, cols: slice) -> RegionBox:
        """The same region in a map that covers only ``rows`` x ``cols`` of the frame (a box
        containing this one)."""
        return RegionBox(slice(self.rows.start - rows.start, self.rows.stop - rows.start),
                         slice(self.cols.start - cols.start, self.cols.stop - cols.start), self.mask)

    @property
    def pixels(self) -> int:
        return int(self.mask.sum())

    def stats(self, values: np.ndarray) -> RegionStats:
        return region_stats(values[self.rows, self.cols], self.mask)

    def mean(self, values: np.ndarray) -> float:
        return region_mean(values[self.rows, self.cols], self.mask)


def bounding_box(masks: list[np.ndarray]) -> tuple[slice, slice]:
    """Rows and columns of the smallest box holding every True pixel of ``masks``."""
    covered = np.logical_or.reduce([np.asarray(mask, bool) for mask in masks]) if masks else np.zeros((0, 0), bool)
    rows, cols = np.flatnonzero(covered.any(axis=1)), np.flatnonzero(covered.any(axis=0))
    if rows.size == 0:
        raise EstimatorError("region is empty")
    return slice(int(rows[0]), int(rows[-1]) + 1), slice(int(cols[0]), int(cols[-1]) + 1)
