"""The time history of the speckle pattern (THSP) of one line or column, its co-occurrence
matrix (COM) and the COM's inertia moment and AVD: the numerical descriptors of BSLTL 1.3.1
(``thsp.m``, ``coom.m``, ``inertiamoment.m``, ``avd.m``; Arizaga et al. 1999 for the THSP and
its moments). Pure: arrays in, arrays and numbers out.

The THSP of row r (or column c) puts each pixel of that line in one row and time along the
columns: THSP[p, k] = I_k(r, p) (or I_k(p, c)), k = 0 .. N-1. The COM counts the transitions
between consecutive times: COM[a, b] = #{(p, k): round(THSP[p, k]) = a, round(THSP[p, k+1]) = b},
a 256 x 256 matrix of counts as in ``coom.m``, where intensities are rounded (halves away from
0, as Octave's round) and clipped to 0..255: data of more than 8 bits must be scaled to 8 bits
first (the ``edgedsm thsp`` command does so), or its values above 255 all fall in the last bin.
"""

from __future__ import annotations

import numpy as np

from edgedsm.errors import EstimatorError
from edgedsm.estimators.batch import check_frames

#: The COM's size in BSLTL's ``coom.m`` (8-bit grey levels).
LEVELS = 256


def thsp(frames: np.ndarray, *, row: int | None = None, column: int | None = None) -> np.ndarray:
    """BSLTL ``thsp(DATA, 'line', row)`` or ``thsp(DATA, 'column', column)`` (0-based index here,
    1-based there): a (W, N) or (H, N) float64 image, grey levels; one of row, column."""
    stack = check_frames(frames)
    if (row is None) == (column is None):
        raise EstimatorError("give exactly one of row, column")
    n, height, width = stack.shape
    if n < 2:
        raise EstimatorError(f"a THSP needs N >= 2 frames, got N={n}")
    index, size, what = (row, height, "row") if row is not None else (column, width, "column")
    if isinstance(index, bool) or not isinstance(index, int | np.integer) or not 0 <= index < size:
        raise EstimatorError(f"{what} {index!r} is outside the {size} {what}s 0..{size - 1} of the frames")
    line = stack[:, index, :] if row is not None else stack[:, :, index]
    return np.ascontiguousarray(line.T, dtype=np.float64)


def _round_half_away(values: np.ndarray) -> np.ndarray:
    """Octave's round for values >= 0: halves go up (numpy's round goes to even)."""
    low = np.floor(values)
    return np.where(values - low >= 0.5, low + 1, low)


def coom(image: np.ndarray) -> np.ndarray:
    """BSLTL ``coom.m``: the (256, 256) int64 co-occurrence matrix of a THSP image (rows are
    pixels, columns times); COM[a, b] counts a pixel at level a followed by level b (module doc)."""
    image = np.asarray(image)
    if image.ndim != 2 or image.shape[1] < 2 or image.shape[0] < 1:
        raise EstimatorError(f"a THSP image is (pixels, N >= 2 times), got shape {image.shape}")
    if not np.isfinite(image).all():
        raise EstimatorError("the THSP image contains NaN or inf")
    levels = np.clip(_round_half_away(image.astype(np.float64)), 0, LEVELS - 1).astype(np.int64)
    pairs = levels[:, :-1] * LEVELS + levels[:, 1:]
    return np.bincount(pairs.ravel(), minlength=LEVELS * LEVELS).reshape(LEVELS, LEVELS)


def _moment(com: np.ndarray, weight: np.ndarray) -> float:
    com = np.asarray(com)
    if com.shape != (LEVELS, LEVELS):
        raise EstimatorError(f"the co-occurrence matrix must be {LEVELS} x {LEVELS}, got {com.shape}")
    if not np.issubdtype(com.dtype, np.integer) or (com < 0).any():
        raise EstimatorError("the co-occurrence matrix must hold counts (integers >= 0)")
    total = int(com.sum())
    if total == 0:
        raise EstimatorError("the co-occurrence matrix is empty (no transitions)")
    # exact integer numerator, one rounding in the division
    return int((com.astype(np.int64) * weight).sum()) / total


_I, _J = np.indices((LEVELS, LEVELS))


def inertia_moment(com: np.ndarray) -> float:
    """BSLTL ``inertiamoment.m``: IM = Σ_ij COM[i, j] (i - j)² / Σ_ij COM[i, j], grey levels².
    (For 8-bit data it equals the mean over the line's pixels of ``descriptors.im`` at m = 1.)"""
    return _moment(com, (_I - _J) ** 2)


def avd(com: np.ndarray) -> float:
    """BSLTL ``avd.m``: AVD = Σ_ij COM[i, j] |i - j| / Σ_ij COM[i, j], grey levels (the absolute
    value of the differences; for 8-bit data the line's mean of S1 at m = 1)."""
    return _moment(com, np.abs(_I - _J))
