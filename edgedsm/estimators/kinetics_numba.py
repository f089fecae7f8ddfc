"""One pass of :class:`edgedsm.estimators.kinetics.Kinetics`' push over an integer frame: each region
pixel's box mean, its ratio r = (I - μ_dark)/M, and the sums the frame's <r>, β and verdict need.

The same arithmetic as the NumPy path (``Kinetics._store`` with ``_Layout.local_means``), fused:
the box sums run down the rows and across the columns as running integer sums (exact), so the
frame is read once instead of in the NumPy path's dozen whole-array passes (docs/kinetics.md,
"Cost", measures both). numba is the optional extra ``fast``; without it the NumPy path runs.
"""

from __future__ import annotations

import functools
import importlib.util
from collections.abc import Callable
from typing import Any

import numpy as np

from edgedsm.estimators.jit import compiled


def _store_source(outer: np.ndarray, row0: int, col0: int, row_low: np.ndarray, row_high: np.ndarray,
                  col_low: np.ndarray, col_high: np.ndarray, inner: np.ndarray, full: bool, dark: float,
                  lut: np.ndarray, lit_level: float, top: float,
                  out: np.ndarray) -> tuple[float, float, float, int, int]:
    """Write r of every region pixel (row-major, the mask's order) into ``out``; return Σr, Σr²,
    Σ σ²(I)·(1 - 1/B)/M², the lit pixels and the saturated ones. ``outer``: the frame's pixels the
    boxes reach; the region's bounding box starts at (``row0``, ``col0``) in it; box rows of bounding
    row y are [row_low[y], row_high[y]) of ``outer``, columns likewise."""
    width = outer.shape[1]
    per_col = 1.0 / (col_high - col_low)
    down = np.zeros(width, np.int64)  # column sums over the current box rows
    across = np.zeros(width + 1, np.int64)  # their running sum along the row
    low = row_low[0]
    high = row_low[0]
    index = 0
    total = 0.0
    squares = 0.0
    noise = 0.0
    lit = 0
    saturated = 0
    for y in range(row_low.size):
        while high < row_high[y]:
            for x in range(width):
                down[x] += outer[high, x]
            high += 1
        while low < row_low[y]:
            for x in range(width):
                down[x] -= outer[low, x]
            low += 1
        for x in range(width):
            across[x + 1] = across[x] + down[x]
        per_row = 1.0 / (row_high[y] - row_low[y])
        for x in range(col_low.size):
            if not full and not inner[y, x]:
                continue
            share = per_row * per_col[x]  # 1/B, B the box's pixel count
            level = (across[col_high[x]] - across[col_low[x]]) * share - dark
            value = outer[row0 + y, col0 + x]
            scale = lit_level
            if level > lit_level:
                scale = level
                lit += 1
            inverse = 1.0 / scale
            ratio = (value - dark) * inverse
            out[index] = ratio
            index += 1
            total += ratio
            squares += ratio * ratio
            noise += lut[value] * (1.0 - share) * inverse * inverse
            if value >= top:
                saturated += 1
    return total, squares, noise, lit, saturated


@functools.cache
def fused_store() -> Callable[..., Any] | None:
    """The compiled pass (numba imported on first use), or None without numba."""
    if importlib.util.find_spec("numba") is None:  # numba is the optional 'fast' extra
        return None
    return compiled(nogil=True)(_store_source)
