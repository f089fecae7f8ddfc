"""S1, S2, σ and S3 (paper Eq. 1-4), and the temporal contrast, Fujii and inertia moment
(issue 24, BSLTL's stdcont, fujii, graphim) of one pixel from a window's sums: the arithmetic
written once.

Every consumer of the engine's sums turns them into values here: the engine's maps kernel, its
snapshots (:func:`edgedsm.estimators.snapshot.maps_from`), the region statistics
(:mod:`edgedsm.estimators.region_stats`: the row buffers and the percentile samples) and the
exponential mode's maps. Each value is one ``@njit(inline="always")`` function of one pixel's
sums, so a kernel that calls it compiles the same float64 operations in the same order: its
results are bit-identical wherever they are formed.

Units: S1 and σ in grey levels, S2, S3, contrast and Fujii dimensionless, IM in grey levels²;
N (``n``) and N - m (``pairs``) in frames. Inputs:

- window modes (sliding, tumbling): the integer sums Σ|I_j - I_{j+m}| (``abs_sum``), the
  fixed-point Σ S2 term in units of ``ratio_unit`` = 2^-K (:mod:`edgedsm.estimators.fixed_point`),
  ΣI (``total``) and ΣI² (``total_sq``) over N frames, and Σ(I_j - I_{j+m})² (``sq_sum``);
- exponential mode: the weighted means of |ΔI|, of the S2 term and of (ΔI)² (already the
  values) and the weighted mean and M2 with the frames' total weight Σλ^k (``weight``),
  σ² = M2/Σλ^k.

Degenerate pixels: S3 = 0 where σ = 0 (constant or saturated pixel), contrast = 0 where ⟨I⟩ = 0
(dark pixel); nothing is NaN or inf.

Like scikit-image's compiled kernels beside their numeric twins, the NumPy functions at the end
(``*_values``, ``window_sigmas``) compute the same maps for whole arrays where numba is absent
(the optional ``fast`` extra); they evaluate the same expressions in the same order, and tests
hold the two equal bit for bit (tests/unit/estimators/test_activity_values.py).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

from edgedsm.estimators.registry import VALUES, KernelSpec
from edgedsm.estimators.value_set import INT64_MAX, window_spreads

try:
    import numba
except ImportError:  # numba is the optional 'fast' extra: the NumPy twins below serve
    numba = None


def _inline(function: Callable[..., Any]) -> Callable[..., Any]:
    """Compiled for inlining into the kernels that call it (plain Python without numba)."""
    if numba is None:
        return function
    return numba.njit(inline="always", nogil=True, cache=True)(function)


@_inline
def s1_value(abs_sum, pairs):  # pragma: no cover - compiled
    """Eq. 1: S1 = Σ|ΔI|/(N-m), the correctly rounded quotient (as ``batch.s1``)."""
    return np.float64(abs_sum) / pairs


@_inline
def s2_value(ratio_sum, ratio_unit, pairs):  # pragma: no cover - compiled
    """Eq. 2: S2 = ΣT·2^-K/(N-m) (multiplying by the power of two 2^-K is exact)."""
    return np.float64(ratio_sum) * ratio_unit / pairs


@_inline
def centred_spread(s, total_sq, n, k, limit):  # pragma: no cover - compiled
    """N²σ² (Eq. 4) of a pixel from its integer sums ΣI = ``s`` and ΣI² = ``total_sq`` over N =
    ``n`` frames: N·Σ(I-k)² - r² with r = ΣI - kN, for any integer ``k`` (round(ΣI/N) keeps both
    terms small), exact in int64 while N·Σ(I-k)² <= ``limit`` = (2^63 - 1) // N."""
    r = s - k * n
    centred = total_sq - k * (s + r)
    if centred <= limit:
        return np.float64(n * centred - r * r)
    return n * np.float64(centred) - np.float64(r * r)  # r² <= (N/2+1)² is negligible beside >= 2^63


@_inline
def window_sigma(total, total_sq, n):  # pragma: no cover - compiled
    """Eq. 4: σ = sqrt(N·ΣI² - (ΣI)²)/N over N = ``n`` frames, from the integer sums, with
    k = round(ΣI/N) (docs/engine.md: exact in int64, else a cancellation-free float64)."""
    s = np.int64(total)
    k = np.int64(np.floor(np.float64(s) / n + 0.5))
    return np.sqrt(centred_spread(s, np.int64(total_sq), n, k, np.int64(INT64_MAX) // n)) / n


@_inline
def weighted_sigma(m2, weight):  # pragma: no cover - compiled
    """σ of the exponential mode: sqrt(M2/Σλ^k) (M2 >= 0 by construction)."""
    return np.sqrt(m2 / weight)


@_inline
def s3_value(s1, sigma):  # pragma: no cover - compiled
    """Eq. 3: S3 = S1/σ, 0 where σ = 0 (every intensity of the window equal)."""
    return s1 / sigma if sigma > 0.0 else 0.0


@_inline
def contrast_value(sigma, mean):  # pragma: no cover - compiled
    """Temporal contrast σ/⟨I⟩ (BSLTL ``stdcont.m``, population σ of Eq. 4), 0 where ⟨I⟩ = 0
    (a dark pixel, where σ is 0 too). Dimensionless."""
    return sigma / mean if mean > 0.0 else 0.0


@_inline
def window_mean(total, n):  # pragma: no cover - compiled
    """⟨I⟩ = ΣI/N over N = ``n`` frames from the exact integer sum (as descriptors._mean), grey levels."""
    return np.float64(total) / n


@_inline
def fujii_value(s2):  # pragma: no cover - compiled
    """Fujii's map, BSLTL ``fujii.m``: 200·S2 with S2 at q = 0 (Eq. 2); dimensionless, 0..200."""
    return 200.0 * s2


@_inline
def im_value(sq_sum, pairs):  # pragma: no cover - compiled
    """Inertia moment, BSLTL ``graphim.m``: Σ(I_k - I_{k+m})²/(N-m), grey levels² (the exact
    integer sum divided once, as ``descriptors.im``)."""
    return np.float64(sq_sum) / pairs


@_inline
def pixel_values(exponential, do_abs, do_s2, do_s3, do_contrast, do_fujii, do_im, p, abs_sum, ratio_sum, second,
                 fourth, sq_sum, pairs, ratio_unit, n, weight):  # pragma: no cover - compiled
    """(S1, S2, S3, σ, contrast, Fujii, IM) of flat pixel ``p``; the values not asked for
    (``do_*``, compile-time constants in the callers) are 0. ``do_s2``: S2 is formed (S2 or Fujii
    asked for). ``second``/``fourth``: ΣI and ΣI² (window modes) or the weighted mean and M2
    (``exponential``); ``sq_sum``: Σ(ΔI)² (window modes) or its weighted mean."""
    s1 = 0.0
    s2 = 0.0
    s3 = 0.0
    sigma = 0.0
    contrast = 0.0
    fujii = 0.0
    inertia = 0.0
    if do_abs:
        s1 = abs_sum[p] if exponential else s1_value(abs_sum[p], pairs)
    if do_s2:
        s2 = ratio_sum[p] if exponential else s2_value(ratio_sum[p], ratio_unit, pairs)
        if do_fujii:
            fujii = fujii_value(s2)
    if do_s3 or do_contrast:
        sigma = weighted_sigma(fourth[p], weight) if exponential else window_sigma(second[p], fourth[p], n)
        if do_s3:
            s3 = s3_value(s1, sigma)
        if do_contrast:
            contrast = contrast_value(sigma, second[p] if exponential else window_mean(second[p], n))
    if do_im:
        inertia = sq_sum[p] if exponential else im_value(sq_sum[p], pairs)
    return s1, s2, s3, sigma, contrast, fujii, inertia


# -- NumPy twins (whole arrays; used where numba is absent) ------------------------------------


def s1_values(abs_sum: np.ndarray, pairs: int, out: np.ndarray) -> None:
    """:func:`s1_value` of every pixel, into ``out``."""
    np.divide(abs_sum.astype(np.float64), pairs, out=out)


def s2_values(ratio_sum: np.ndarray, ratio_unit: float, pairs: int, out: np.ndarray) -> None:
    """:func:`s2_value` of every pixel, into ``out``."""
    scaled = ratio_sum.astype(np.float64)
    scaled *= ratio_unit
    np.divide(scaled, pairs, out=out)


def window_sigmas(total: np.ndarray, total_sq: np.ndarray, n: int) -> np.ndarray:
    """:func:`window_sigma` of every pixel (new float64 array)."""
    return np.sqrt(window_spreads(total, total_sq, n)) / n


def s3_values(s1: np.ndarray, sigma: np.ndarray, out: np.ndarray) -> None:
    """:func:`s3_value` of every pixel, into ``out``."""
    out[:] = 0.0
    np.divide(s1, sigma, out=out, where=sigma > 0.0)


def contrast_values(sigma: np.ndarray, mean: np.ndarray, out: np.ndarray) -> None:
    """:func:`contrast_value` of every pixel, into ``out``."""
    out[:] = 0.0
    np.divide(sigma, mean, out=out, where=mean > 0.0)


def fujii_values(s2: np.ndarray, out: np.ndarray) -> None:
    """:func:`fujii_value` of every pixel, into ``out``."""
    np.multiply(200.0, s2, out=out)


def im_values(sq_sum: np.ndarray, pairs: int, out: np.ndarray) -> None:
    """:func:`im_value` of every pixel, into ``out``."""
    np.divide(sq_sum.astype(np.float64), pairs, out=out)


def values_numpy(exponential: bool, spec: KernelSpec | tuple[bool, ...], abs_sum: np.ndarray, ratio_sum: np.ndarray,
                 second: np.ndarray, fourth: np.ndarray, sq_sum: np.ndarray, pairs: int, ratio_unit: float, n: int,
                 weight: float, out: Mapping[str, np.ndarray]) -> None:
    """:func:`pixel_values` of every pixel, into the arrays ``out`` (by the names of
    :data:`~edgedsm.estimators.registry.VALUES`) of the values ``spec`` asks for."""
    do_abs, do_s2, do_s3, do_contrast, do_fujii, do_im = spec.flags if isinstance(spec, KernelSpec) else spec
    s1, s2, s3, sigma, contrast, fujii, im = (out[name] for name in VALUES)
    if do_abs:
        if exponential:
            s1[:] = abs_sum
        else:
            s1_values(abs_sum, pairs, s1)
    if do_s2:
        if exponential:
            s2[:] = ratio_sum
        else:
            s2_values(ratio_sum, ratio_unit, pairs, s2)
        if do_fujii:
            fujii_values(s2, fujii)
    if do_s3 or do_contrast:
        sigma[:] = np.sqrt(fourth / weight) if exponential else window_sigmas(second, fourth, n)
        if do_s3:
            s3_values(s1, sigma, s3)
        if do_contrast:
            contrast_values(sigma, second if exponential else second.astype(np.float64) / n, contrast)
    if do_im:
        if exponential:
            im[:] = sq_sum
        else:
            im_values(sq_sum, pairs, im)
