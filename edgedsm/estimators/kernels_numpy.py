"""NumPy kernels of the streaming engine: the fallback when numba is not installed.

Same factories, arguments and bit-identical results as
:mod:`edgedsm.estimators.kernels_numba` (tested); see that module and
:mod:`edgedsm.estimators.moment_sums` for what each sum means. The pass over the pixels is cut
into chunks of :data:`CHUNK` pixels so the temporaries stay in cache: the frame and the sums
are still read and written once per frame, as in the fused numba pass, but on one thread.
The factories take ``parallel`` for symmetry with numba and ignore it.
Floating-point expressions are evaluated in the same order as there, so every rounding
matches.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np

from edgedsm.estimators.activity import values_numpy
from edgedsm.estimators.activity import window_sigmas as sigma_from_sums
from edgedsm.estimators.fixed_point import ROUNDING, ROUNDING_BITS
from edgedsm.estimators.registry import VALUES, KernelSpec
from edgedsm.estimators.value_set import maps_kernel_args

KERNEL = "numpy"
__all__ = ["CHUNK", "KERNEL", "batch_products_kernel", "batch_slide_kernel", "dft_kernel", "exponential_kernel",
           "gd_kernel", "maps_kernel", "max_threads", "pairs_kernel", "products_kernel", "set_threads",
           "sigma_from_sums", "window_kernel"]
CHUNK = 1 << 15  # pixels per chunk: the int64/float64 temporaries (256 KiB each) stay in L2


def set_threads(threads: int | None) -> None:
    """The NumPy kernels run on the calling thread; ``threads`` is accepted and ignored."""


def max_threads() -> int:
    """The NumPy kernels use one thread."""
    return 1


def _ratio_terms(kind: str, a: np.ndarray, b: np.ndarray, lut: np.ndarray, scale: float,
                 q: float) -> np.ndarray:
    """Eq. 2 terms |a-b|/(a+b+q) in fixed point, int64 (see kernels_numba._ratio_term)."""
    if kind == "lut":
        return lut[(a << 8) | b]
    diff = np.abs(a - b)
    if kind == "exact":
        one = np.int64(scale)
        denominator = np.maximum(a + b + np.int64(q), 1)
        estimate = diff.astype(np.float64) / denominator.astype(np.float64) * scale + 0.5
        t = np.floor(estimate).astype(np.int64)
        rest = 2 * (diff * one - t * denominator) + denominator
        t -= rest < 0
        t += rest >= 2 * denominator
        return t
    denominator = np.maximum((a + b).astype(np.float64) + q, 1.0)
    ratio = diff / denominator
    ratio *= scale
    ratio += ROUNDING  # rounds y to an integer T, ties to even: its bits are ROUNDING_BITS + T
    return ratio.view(np.int64) - ROUNDING_BITS


@functools.cache
def window_kernel(do_abs: bool, do_ratio: bool, do_sigma: bool, ratio_kind: str,
                  remove: bool, parallel: bool = True, do_sq: bool = False) -> Callable[..., None]:
    """See kernels_numba.window_kernel."""

    def kernel(new, slot, lagged, leaving, abs_sum, ratio_sum, total, total_sq, sq_sum,
               lut, scale, q) -> None:
        for start in range(0, new.size, CHUNK):
            part = slice(start, start + CHUNK)
            # copies: everything is read before the slot is overwritten
            x = new[part].astype(np.int64)
            a = lagged[part].astype(np.int64)
            o = slot[part].astype(np.int64) if remove else None
            b = leaving[part].astype(np.int64) if remove else None
            slot[part] = new[part]
            if do_sigma:
                t = total[part].astype(np.int64)
                t2 = total_sq[part].astype(np.int64)
                t += x
                t2 += x * x
                if o is not None:
                    t -= o
                    t2 -= o * o
                total[part] = t
                total_sq[part] = t2
            if do_abs:
                s = abs_sum[part].astype(np.int64)
                if o is not None and b is not None:
                    s -= np.abs(b - o)
                s += np.abs(x - a)
                abs_sum[part] = s
            if do_sq:
                u = sq_sum[part].astype(np.int64)
                if o is not None and b is not None:
                    u -= (b - o) * (b - o)
                u += (x - a) * (x - a)
                sq_sum[part] = u
            if do_ratio:
                r = ratio_sum[part]  # a view: updated in place
                if o is not None and b is not None:
                    r -= _ratio_terms(ratio_kind, o, b, lut, scale, q)
                r += _ratio_terms(ratio_kind, a, x, lut, scale, q)

    return kernel


@functools.cache
def pairs_kernel(do_abs: bool, do_ratio: bool, ratio_kind: str,
                 parallel: bool = True, do_sq: bool = False) -> Callable[..., None]:
    """See kernels_numba.pairs_kernel."""

    def kernel(first, second, abs_sum, ratio_sum, sq_sum, lut, scale, q) -> None:
        for start in range(0, first.size, CHUNK):
            part = slice(start, start + CHUNK)
            a = first[part].astype(np.int64)
            b = second[part].astype(np.int64)
            if do_abs:
                abs_sum[part] = abs_sum[part].astype(np.int64) + np.abs(b - a)
            if do_sq:
                sq_sum[part] = sq_sum[part].astype(np.int64) + (b - a) * (b - a)
            if do_ratio:
                ratio_sum[part] += _ratio_terms(ratio_kind, a, b, lut, scale, q)

    return kernel


@functools.cache
def exponential_kernel(do_abs: bool, do_ratio: bool, do_sigma: bool,
                       parallel: bool = True, do_sq: bool = False) -> Callable[..., None]:
    """See kernels_numba.exponential_kernel."""

    def kernel(new, slot, mean, m2, abs_mean, ratio_mean, sq_mean, decay, w_frame, w_pair, q) -> None:
        for start in range(0, new.size, CHUNK):
            part = slice(start, start + CHUNK)
            x = new[part].astype(np.float64)
            a = slot[part].astype(np.float64)
            slot[part] = new[part]
            if do_sigma:
                mu = mean[part]
                delta = x - mu
                mu_new = mu + w_frame * delta
                mean[part] = mu_new
                m2[part] = decay * m2[part] + delta * (x - mu_new)
            diff = np.abs(x - a)
            if do_abs:
                y = abs_mean[part]
                abs_mean[part] = y + w_pair * (diff - y)
            if do_sq:
                v = sq_mean[part]
                sq_mean[part] = v + w_pair * (diff * diff - v)
            if do_ratio:
                ratio = diff / np.maximum(x + a + q, 1.0)
                z = ratio_mean[part]
                ratio_mean[part] = z + w_pair * (ratio - z)

    return kernel


def maps_kernel(spec: KernelSpec | bool, *legacy: bool, **options: bool) -> Callable[..., None]:
    """See kernels_numba.maps_kernel (the NumPy twins of edgedsm.estimators.activity)."""
    return _maps_kernel(*maps_kernel_args(spec, *legacy, **options))


@functools.cache
def _maps_kernel(spec: KernelSpec, parallel: bool, exponential: bool) -> Callable[..., None]:
    def kernel(abs_sum, ratio_sum, second, fourth, sq_sum, pairs, ratio_unit, n, s1, s2, s3, sigma, contrast, fujii,
               im, weight) -> None:
        out = dict(zip(VALUES, (s1, s2, s3, sigma, contrast, fujii, im), strict=True))
        values_numpy(exponential, spec, abs_sum, ratio_sum, second, fourth, sq_sum, pairs, ratio_unit, n, weight,
                     out)

    return kernel


@functools.cache
def products_kernel(remove: bool, parallel: bool = True, narrow: bool = False) -> Callable[..., None]:
    """See kernels_numba.products_kernel (``narrow`` is ignored: int64 gives the same integers)."""

    def kernel(new, ring, old_slot, lag_slots, leave_slots, products, lags) -> None:
        count = lag_slots.size if remove else lags
        for start in range(0, new.size, CHUNK):
            part = slice(start, start + CHUNK)
            x = new[part].astype(np.int64)
            o = ring[old_slot, part].astype(np.int64) if remove else None
            for k in range(count):
                value = products[k, part].astype(np.int64)
                if o is not None:
                    value -= o * ring[leave_slots[k], part]
                value += x * ring[lag_slots[k], part]
                products[k, part] = value

    return kernel


@functools.cache
def batch_products_kernel(parallel: bool = True, narrow: bool = False) -> Callable[..., None]:
    """See kernels_numba.batch_products_kernel."""

    def kernel(ring, frame_slots, lag_slots, lag_counts, products) -> None:
        for start in range(0, ring.shape[1], CHUNK):
            part = slice(start, start + CHUNK)
            for k in range(products.shape[0]):
                value = products[k, part].astype(np.int64)
                for b in range(frame_slots.size):
                    if k < lag_counts[b]:
                        value += ring[frame_slots[b], part].astype(np.int64) * ring[lag_slots[b, k], part]
                products[k, part] = value

    return kernel


@functools.cache
def batch_slide_kernel(parallel: bool = True, narrow: bool = False) -> Callable[..., None]:
    """See kernels_numba.batch_slide_kernel."""

    def kernel(ring, retired, new_slots, old_slots, lag_slots, leave_slots, leave_retired, products) -> None:
        for start in range(0, ring.shape[1], CHUNK):
            part = slice(start, start + CHUNK)
            for k in range(products.shape[0]):
                value = products[k, part].astype(np.int64)
                for b in range(new_slots.size):
                    source = retired if leave_retired[b, k] else ring
                    value -= retired[old_slots[b], part].astype(np.int64) * source[leave_slots[b, k], part]
                    value += ring[new_slots[b], part].astype(np.int64) * ring[lag_slots[b, k], part]
                products[k, part] = value

    return kernel


@functools.cache
def gd_kernel(remove: bool, parallel: bool = True) -> Callable[..., None]:
    """See kernels_numba.gd_kernel."""

    def kernel(new, ring, old_slot, count, gd_sum) -> None:
        for start in range(0, new.size, CHUNK):
            part = slice(start, start + CHUNK)
            x = new[part].astype(np.int64)
            old = ring[old_slot, part].astype(np.int64)
            acc = np.zeros(x.size, np.int64)
            for k in range(count):
                if remove and k == old_slot:
                    continue
                row = ring[k, part].astype(np.int64)
                acc += np.abs(x - row)
                if remove:
                    acc -= np.abs(old - row)
            gd_sum[part] += acc

    return kernel


@functools.cache
def dft_kernel(rotate: bool, parallel: bool = True) -> Callable[..., None]:
    """See kernels_numba.dft_kernel."""

    def kernel(new, old, cos, sin, bins) -> None:
        for start in range(0, new.size, CHUNK):
            part = slice(start, start + CHUNK)
            d = new[part].astype(np.float64) - old[part].astype(np.float64)
            for b in range(cos.size):
                re, im = bins[0, b, part], bins[1, b, part]
                if rotate:
                    a = re + d
                    y = im.copy()
                    re[:] = cos[b] * a - sin[b] * y
                    im[:] = sin[b] * a + cos[b] * y
                else:
                    re += d * cos[b]
                    im -= d * sin[b]

    return kernel
