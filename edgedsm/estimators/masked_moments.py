"""The region-statistics pass (:func:`masked_moments`): count, mean, standard deviation and an
even sample of the pixels of a map inside a mask, in two passes over the region's box and no copy
of it (used by :mod:`edgedsm.estimators.region_stats` and :mod:`edgedsm.estimators.region_box`).

The numba version releases the GIL (``nogil``): the evaluator thread computes statistics while
the pipeline thread pushes frames. Sums are compensated (Neumaier), so the mean and the
deviation are within a few units of roundoff of the exact values whatever the region's size
(numpy's pairwise sums are within O(log n) units). The numpy version, used without numba,
gives the same sample and agrees within that rounding.
"""

from __future__ import annotations

import functools
import importlib.util
from collections.abc import Callable
from typing import Any

import numpy as np

from edgedsm.estimators.jit import compiled


def masked_moments_numpy(values: np.ndarray, mask: np.ndarray, samples: int) -> tuple[int, float, float, np.ndarray]:
    """:func:`masked_moments` in NumPy (a copy of the selected pixels, numpy's pairwise sums): the
    pass without numba, and the compiled one's reference in the tests."""
    selected = values[mask]
    if selected.size == 0:
        return 0, 0.0, 0.0, selected
    stride = -(-selected.size // samples)
    return (int(selected.size), float(selected.mean(dtype=np.float64)), float(selected.std(dtype=np.float64)),
            selected[::stride])


def _moments_source(values, mask, samples):  # pragma: no cover - compiled
    rows, cols = values.shape
    count = 0
    total = 0.0
    carry = 0.0
    for i in range(rows):
        for j in range(cols):
            if mask[i, j]:
                x = np.float64(values[i, j])
                count += 1
                t = total + x
                carry += (total - t) + x if abs(total) >= abs(x) else (x - t) + total
                total = t
    if count == 0:
        return 0, 0.0, 0.0, np.empty(0)
    mean = (total + carry) / count
    stride = (count + samples - 1) // samples
    sample = np.empty((count + stride - 1) // stride)
    squares = 0.0
    carry = 0.0
    index = 0
    for i in range(rows):
        for j in range(cols):
            if mask[i, j]:
                x = np.float64(values[i, j])
                if index % stride == 0:
                    sample[index // stride] = x
                index += 1
                d = (x - mean) * (x - mean)
                t = squares + d
                carry += (squares - t) + d if squares >= d else (d - t) + squares
                squares = t
    return count, mean, np.sqrt((squares + carry) / count), sample


@functools.cache
def _moments() -> Callable[..., Any]:
    """The compiled pass (numba imported on first use), or numpy without numba."""
    if importlib.util.find_spec("numba") is None:  # numba is the optional 'fast' extra
        return masked_moments_numpy
    return compiled(nogil=True)(_moments_source)


def masked_moments(values: np.ndarray, mask: np.ndarray, samples: int) -> tuple[int, float, float, np.ndarray]:
    """(pixels, mean, std, every k-th selected value in row-major order, k = ⌈pixels/samples⌉)
    of ``values`` where ``mask`` (same 2-D shape; views are fine, nothing is copied)."""
    count, mean, std, sample = _moments()(values, mask, samples)
    return int(count), float(mean), float(std), sample
