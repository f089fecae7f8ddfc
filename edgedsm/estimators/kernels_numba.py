"""Numba kernels of the streaming engine: one fused, parallel pass over the pixels per frame.

Same contract and bit-identical results as :mod:`edgedsm.estimators.kernels_numpy` (tested).
Each ``*_kernel(...)`` factory returns a compiled function specialised for one set of sums
(which of Σ|ΔI|, Σ S2 term, ΣI/ΣI² are kept, how S2 terms are formed, with or without
removal): the choices are compile-time constants, so the loop has no branches on them. (With
run-time flags, some combinations ran up to 100x slower with numba 0.68.) The caller picks
the kernel without removal while the window fills, and expresses "no pair yet" by a neutral
input (the frame paired with itself), see :mod:`edgedsm.estimators.moment_sums`.

All functions take flat (1-D, C-contiguous) arrays, update the sums in place and write the
new frame into its ring slot after reading the slot. ``fastmath`` stays off: every
floating-point operation is evaluated as written (no FMA contraction, no reassociation) so
both kernel modules round identically. Compiled code is cached on disk: numba keys the cache on
the closure constants, and :func:`edgedsm.estimators.jit.kernel_variant` names the parallel and
serial variants apart (numba's key leaves out the decorator's options).

``parallel=False`` compiles the same loop for the calling thread alone: for small frames,
waking the worker threads costs more than the work (and on a loaded machine a parallel
region waits for a descheduled worker).

Importing this module imports numba (the optional extra ``fast``); the engine imports it
lazily.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numba
import numpy as np
from numba.extending import intrinsic

from edgedsm.estimators.activity import pixel_values
from edgedsm.estimators.fixed_point import ROUNDING, ROUNDING_BITS
from edgedsm.estimators.jit import kernel_variant
from edgedsm.estimators.registry import KernelSpec
from edgedsm.estimators.value_set import maps_kernel_args

KERNEL = "numba"


def set_threads(threads: int | None) -> None:
    """Use ``threads`` worker threads for the next kernel calls (None: numba's default)."""
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS if threads is None else threads)


def max_threads() -> int:
    """Largest thread count :func:`set_threads` accepts."""
    return int(numba.config.NUMBA_NUM_THREADS)


@intrinsic
def _float_bits(typingctx, value):  # pragma: no cover - compiled
    """The bits of a float64 as an int64 (a bit cast: no conversion instruction)."""
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], context.get_value_type(numba.types.int64))
    return numba.types.int64(numba.types.float64), codegen


@numba.njit(inline="always", cache=True)
def _rounded(y):  # pragma: no cover - compiled
    """y (0 <= y < 2^52) rounded to the nearest integer, ties to even: the bits of y + 2^52 less
    those of 2^52 (fixed_point.ROUNDING)."""
    return _float_bits(y + ROUNDING) - ROUNDING_BITS


@numba.njit(inline="always", cache=True)
def _ratio_term(kind, a, b, lut, scale, q, one, q_int):  # pragma: no cover - compiled
    """Eq. 2 term |a-b|/(a+b+q) in fixed point (scale 2^K), int64.

    kind "exact" (integer q, K <= 51): round half up of |a-b|·2^K/(a+b+q), exactly: a float
    estimate within 1/4 of the true value, then one integer correction step.
    kind "lut": the exactly rounded value from the 8-bit table, index (a << 8) | b.
    kind "float": y = fl(|a-b| / max(fl(a+b+q), 1))·2^K, and T = y rounded to an integer, ties
    to even, read off the bits of y + 2^52 (0 <= y < 2^52 as K <= 51): an add and an integer
    subtract, cheaper than floor and a float-to-int conversion (docs/engine.md, "S2's term").
    The denominator is raised to at least 1: it is below 1 only when a = b = 0, where the
    term is 0 whatever it is divided by (no branch, no 0/0).
    """
    if kind == "lut" or (kind == "exact" and lut.size):
        return lut[(a << 8) | b]
    diff = abs(a - b)
    if kind == "exact":
        denominator = max(a + b + q_int, np.int64(1))
        t = np.int64(np.floor(np.float64(diff) / np.float64(denominator) * scale + 0.5))
        # t is right iff 0 <= 2·(diff·2^K - t·d) + d < 2d; the estimate is off by <= 1
        rest = 2 * (diff * one - t * denominator) + denominator
        # arithmetic, not branches: the correction is data-dependent and must not stall
        return t + np.int64(rest >= 2 * denominator) - np.int64(rest < 0)
    return _rounded(diff / max(np.float64(a + b) + q, 1.0) * scale)


@functools.cache
def window_kernel(do_abs: bool, do_ratio: bool, do_sigma: bool, ratio_kind: str,
                  remove: bool, parallel: bool = True, do_sq: bool = False) -> Callable[..., None]:
    """Kernel of the integer engine (sliding: ``remove``; tumbling: not), all pixels.

    ``kernel(new, slot, lagged, leaving, abs_sum, ratio_sum, total, total_sq, sq_sum, lut,
    scale, q)``: per pixel it reads I_i (``new``), frame i-m (``lagged``) and, with ``remove``,
    frame i-N (``slot``) and frame i-N+m (``leaving``); writes I_i into ``slot``; adds the
    pair (i-m, i) and frame i and, with ``remove``, subtracts the pair (i-N, i-N+m) and
    frame i-N, to and from Σ|ΔI| (Eq. 1), Σ fixed-point S2 term (Eq. 2), ΣI and ΣI² (Eq. 4)
    and, with ``do_sq``, Σ(ΔI)² (the inertia moment's sum).
    ``slot`` must not share memory with another argument: numba may reorder accesses to
    distinct arguments (read-only arguments may alias each other).
    """

    @kernel_variant(parallel)
    def kernel(new, slot, lagged, leaving, abs_sum, ratio_sum, total, total_sq, sq_sum,
               lut, scale, q):  # pragma: no cover - compiled
        one = np.int64(scale)  # 2^K, exact
        q_int = np.int64(q) if ratio_kind == "exact" else np.int64(0)
        for p in numba.prange(new.size):
            x = np.int64(new[p])
            a = np.int64(lagged[p])
            o = np.int64(slot[p]) if remove else np.int64(0)
            b = np.int64(leaving[p]) if remove else np.int64(0)
            slot[p] = new[p]
            if do_sigma:
                t = np.int64(total[p]) + x
                t2 = np.int64(total_sq[p]) + x * x
                if remove:
                    t -= o
                    t2 -= o * o
                total[p] = t
                total_sq[p] = t2
            if do_abs:
                s = np.int64(abs_sum[p])
                if remove:  # remove first: the running value stays within the window's range
                    s -= abs(b - o)
                abs_sum[p] = s + abs(x - a)
            if do_sq:
                d = x - a
                u = np.int64(sq_sum[p])
                if remove:
                    e = b - o
                    u -= e * e
                sq_sum[p] = u + d * d
            if do_ratio:
                r = ratio_sum[p]
                if remove:
                    r -= _ratio_term(ratio_kind, o, b, lut, scale, q, one, q_int)
                ratio_sum[p] = r + _ratio_term(ratio_kind, a, x, lut, scale, q, one, q_int)

    return kernel


@functools.cache
def pairs_kernel(do_abs: bool, do_ratio: bool, ratio_kind: str,
                 parallel: bool = True, do_sq: bool = False) -> Callable[..., None]:
    """``kernel(first, second, abs_sum, ratio_sum, sq_sum, lut, scale, q)``: add one pair's terms
    to Σ|ΔI|, Σ S2 term and (``do_sq``) Σ(ΔI)², all pixels (rebuilds the sums from the ring in
    ``resync``)."""

    @kernel_variant(parallel)
    def kernel(first, second, abs_sum, ratio_sum, sq_sum, lut, scale, q):  # pragma: no cover
        one = np.int64(scale)
        q_int = np.int64(q) if ratio_kind == "exact" else np.int64(0)
        for p in numba.prange(first.size):
            a = np.int64(first[p])
            b = np.int64(second[p])
            if do_abs:
                abs_sum[p] = np.int64(abs_sum[p]) + abs(b - a)
            if do_sq:
                sq_sum[p] = np.int64(sq_sum[p]) + (b - a) * (b - a)
            if do_ratio:
                ratio_sum[p] += _ratio_term(ratio_kind, a, b, lut, scale, q, one, q_int)

    return kernel


@functools.cache
def exponential_kernel(do_abs: bool, do_ratio: bool, do_sigma: bool,
                       parallel: bool = True, do_sq: bool = False) -> Callable[..., None]:
    """Kernel of the exponential engine (float64), all pixels.

    ``kernel(new, slot, mean, m2, abs_mean, ratio_mean, sq_mean, decay, w_frame, w_pair, q)``:
    ``slot`` holds frame i-m and receives I_i after it was read. Weighted mean and variance
    follow West's update with old weights decayed by λ = ``decay`` and the new sample
    weighing 1: μ += w·(x-μ), M2 = λ·M2 + (x-μ_old)(x-μ_new), w = 1/Σweights. The pair means
    move by ``w_pair``·(term - mean); ``w_pair`` = 0 leaves them unchanged (no pair yet).
    ``do_sq``: the weighted mean of (ΔI)² (the inertia moment) as well.
    """

    @kernel_variant(parallel)
    def kernel(new, slot, mean, m2, abs_mean, ratio_mean, sq_mean, decay, w_frame, w_pair,
               q):  # pragma: no cover - compiled
        for p in numba.prange(new.size):
            x = np.float64(new[p])
            a = np.float64(slot[p])
            slot[p] = new[p]
            if do_sigma:
                mu = mean[p]
                delta = x - mu
                mu = mu + w_frame * delta
                mean[p] = mu
                m2[p] = decay * m2[p] + delta * (x - mu)
            diff = abs(x - a)
            if do_abs:
                y = abs_mean[p]
                abs_mean[p] = y + w_pair * (diff - y)
            if do_sq:
                v = sq_mean[p]
                sq_mean[p] = v + w_pair * (diff * diff - v)
            if do_ratio:
                # >= 1 unless x = a = 0, where diff = 0 and the term is 0 anyway
                ratio = diff / max(x + a + q, 1.0)
                z = ratio_mean[p]
                ratio_mean[p] = z + w_pair * (ratio - z)

    return kernel


def maps_kernel(spec: KernelSpec | bool, *legacy: bool, **options: bool) -> Callable[..., None]:
    """Kernel turning a window's sums into float64 maps, all pixels, one pass: the values the
    named :class:`~edgedsm.estimators.registry.KernelSpec` asks for
    (``maps_kernel(spec, parallel=True, exponential=False)``; earlier callers' positional
    booleans are accepted, :func:`edgedsm.estimators.value_set.maps_kernel_args`).

    ``kernel(abs_sum, ratio_sum, second, fourth, sq_sum, pairs, ratio_unit, n, s1, s2, s3,
    sigma, contrast, fujii, im, weight)`` writes the values :func:`edgedsm.estimators.activity.pixel_values`
    forms of every pixel (``spec.s2``: S2, which Fujii is formed from; σ with S3 or contrast;
    window modes: the integer sums, ΣI and ΣI² as ``second`` and ``fourth``; ``exponential``: the
    weighted means, mean and M2 as ``second`` and ``fourth``, Σλ^k as ``weight``). Arrays of
    values not formed may be empty.
    """
    return _maps_kernel(*maps_kernel_args(spec, *legacy, **options))


@functools.cache
def _maps_kernel(spec: KernelSpec, parallel: bool, exponential: bool) -> Callable[..., None]:
    # the spec's booleans as plain closure constants: numba folds the branches on them away
    do_abs, do_ratio, do_s3, do_contrast, do_fujii, do_im = spec.flags

    @kernel_variant(parallel)
    def kernel(abs_sum, ratio_sum, second, fourth, sq_sum, pairs, ratio_unit, n, s1, s2, s3, sigma, contrast,
               fujii, im, weight):  # pragma: no cover - compiled
        size = max(s1.size, s2.size, sigma.size, im.size)
        for p in numba.prange(size):
            v1, v2, v3, deviation, vc, vf, vi = pixel_values(exponential, do_abs, do_ratio, do_s3, do_contrast,
                                                             do_fujii, do_im, p, abs_sum, ratio_sum, second,
                                                             fourth, sq_sum, pairs, ratio_unit, n, weight)
            if do_abs:
                s1[p] = v1
            if do_ratio:
                s2[p] = v2
            if do_s3 or do_contrast:
                sigma[p] = deviation
            if do_s3:
                s3[p] = v3
            if do_contrast:
                contrast[p] = vc
            if do_fujii:
                fujii[p] = vf
            if do_im:
                im[p] = vi

    return kernel


PRODUCTS_BLOCK = 2048  # pixels per block of the lag-product kernel: its rows stay in L1
# Pixels per block of the batched lag-product kernels (a 32 KiB int32 row of sums): fewer, longer
# passes along each row per (lag, frames) step than with 2048, 13-16 % faster at 1024², 8-bit,
# K = 20 and 100 (512 and 1024 slower, 16384 the same; docs/engine.md, τc)
BATCH_BLOCK = 8192

# Row helpers of the lag-product kernels: module-level, with the sums' integer type ``wide``
# (np.int32 or np.int64) as an argument the kernels pass as a constant. (As closures inside the
# kernel factories they made the kernels' disk-cache key differ in every process: each start
# compiled them again.) Contiguous 1-D slices: the loops vectorise.


@numba.njit(inline="always", nogil=True, cache=True)
def _slide_rows(wide, row, old, leaving, new, lagged):  # pragma: no cover - compiled
    for p in range(row.size):
        row[p] = wide(row[p]) - wide(old[p]) * wide(leaving[p]) + wide(new[p]) * wide(lagged[p])


@numba.njit(inline="always", nogil=True, cache=True)
def _slide_two(wide, row, o0, v0, n0, l0, o1, v1, n1, l1):  # pragma: no cover - compiled
    for p in range(row.size):  # two frames per load and store of the sums
        row[p] = (wide(row[p]) - wide(o0[p]) * wide(v0[p]) + wide(n0[p]) * wide(l0[p])
                  - wide(o1[p]) * wide(v1[p]) + wide(n1[p]) * wide(l1[p]))


@numba.njit(inline="always", nogil=True, cache=True)
def _add_rows(wide, row, first, second):  # pragma: no cover - compiled
    for p in range(row.size):
        row[p] = wide(row[p]) + wide(first[p]) * wide(second[p])


@numba.njit(inline="always", nogil=True, cache=True)
def _add_four(wide, row, a0, c0, a1, c1, a2, c2, a3, c3):  # pragma: no cover - compiled
    for p in range(row.size):  # four frames per load and store of the sums
        row[p] = (wide(row[p]) + wide(a0[p]) * wide(c0[p]) + wide(a1[p]) * wide(c1[p])
                  + wide(a2[p]) * wide(c2[p]) + wide(a3[p]) * wide(c3[p]))


@functools.cache
def products_kernel(remove: bool, parallel: bool = True, narrow: bool = False) -> Callable[..., None]:
    """Lag products of τc (sliding and tumbling), all pixels: Σ I_t·I_{t+k}, one row per lag.

    ``kernel(new, ring, old_slot, lag_slots, leave_slots, products, lags)``: ``products`` is
    (L, P), int32 or int64, row j for the lag k_j the caller chose (``tau_lags``); per pixel it
    adds I_i·I_{i-k_j} to rows j < ``lags`` (frame i-k_j in ring row ``lag_slots[j]``) and,
    with ``remove``, subtracts I_{i-N}·I_{i-N+k_j} from every row (frame i-N in row
    ``old_slot``, frame i-N+k_j in row ``leave_slots[j]``). Reads
    the ring only: the window kernel writes frame i afterwards. Pixels go in blocks (one per
    task) and, inside a block, lag by lag along contiguous rows, so the loop vectorises and
    the block's frames stay in cache. Integer arithmetic, exact: int64, or with ``narrow``
    (int32 sums, whose every value and partial result fits int32) int32, which vectorises
    twice as wide.
    """
    wide = np.int32 if narrow else np.int64

    @kernel_variant(parallel)
    def kernel(new, ring, old_slot, lag_slots, leave_slots, products, lags):  # pragma: no cover
        size = new.size
        blocks = (size + PRODUCTS_BLOCK - 1) // PRODUCTS_BLOCK
        count = lag_slots.size if remove else lags
        for block in numba.prange(blocks):
            start = block * PRODUCTS_BLOCK
            stop = min(start + PRODUCTS_BLOCK, size)
            x = new[start:stop]
            for k in range(count):
                if remove:
                    _slide_rows(wide, products[k, start:stop], ring[old_slot, start:stop],
                               ring[leave_slots[k], start:stop], x, ring[lag_slots[k], start:stop])
                else:
                    _add_rows(wide, products[k, start:stop], x, ring[lag_slots[k], start:stop])

    return kernel


@functools.cache
def batch_products_kernel(parallel: bool = True, narrow: bool = False) -> Callable[..., None]:
    """Lag products of several frames at once (tumbling τc): fewer passes over the sums.

    ``kernel(ring, frame_slots, lag_slots, lag_counts, products)``: for each b, adds
    I_b·I_{b-k_j} to the rows j < ``lag_counts[b]`` (row j for the lag k_j, ``tau_lags``),
    frame b in ring row ``frame_slots[b]`` and frame b-k_j in row ``lag_slots[b, j]``. Per
    block of pixels, each lag's row of sums is read and written once for all the frames (it
    stays in L1), so the sums move once per batch instead of once per frame. Exact integer
    arithmetic, as products_kernel.
    """
    wide = np.int32 if narrow else np.int64

    @kernel_variant(parallel)
    def kernel(ring, frame_slots, lag_slots, lag_counts, products):  # pragma: no cover
        size = ring.shape[1]
        blocks = (size + BATCH_BLOCK - 1) // BATCH_BLOCK
        count = frame_slots.size
        for block in numba.prange(blocks):
            start = block * BATCH_BLOCK
            stop = min(start + BATCH_BLOCK, size)
            for k in range(products.shape[0]):
                row = products[k, start:stop]
                b = 0
                while b + 4 <= count and k < lag_counts[b] and k < lag_counts[b + 1] \
                        and k < lag_counts[b + 2] and k < lag_counts[b + 3]:
                    _add_four(wide, row, ring[frame_slots[b], start:stop], ring[lag_slots[b, k], start:stop],
                             ring[frame_slots[b + 1], start:stop], ring[lag_slots[b + 1, k], start:stop],
                             ring[frame_slots[b + 2], start:stop], ring[lag_slots[b + 2, k], start:stop],
                             ring[frame_slots[b + 3], start:stop], ring[lag_slots[b + 3, k], start:stop])
                    b += 4
                while b < count:
                    if k < lag_counts[b]:
                        _add_rows(wide, row, ring[frame_slots[b], start:stop], ring[lag_slots[b, k], start:stop])
                    b += 1

    return kernel


@functools.cache
def batch_slide_kernel(parallel: bool = True, narrow: bool = False) -> Callable[..., None]:
    """Sliding τc: the lag products of several frames at once (see batch_products_kernel).

    ``kernel(ring, retired, new_slots, old_slots, lag_slots, leave_slots, leave_retired,
    products)``: for each pending frame b and each row j (lag k_j), adds I_b·I_{b-k_j} (ring
    rows ``new_slots[b]``, ``lag_slots[b, j]``) and subtracts I_{b-N}·I_{b-N+k_j} (frame b-N in
    row ``old_slots[b]`` of ``retired``, frame b-N+k_j in row ``leave_slots[b, j]`` of
    ``retired`` where ``leave_retired[b, j]``, else of ``ring``). Exact integer arithmetic.
    """
    wide = np.int32 if narrow else np.int64

    @kernel_variant(parallel)
    def kernel(ring, retired, new_slots, old_slots, lag_slots, leave_slots, leave_retired,
               products):  # pragma: no cover - compiled
        size = ring.shape[1]
        blocks = (size + BATCH_BLOCK - 1) // BATCH_BLOCK
        count = new_slots.size
        for block in numba.prange(blocks):
            start = block * BATCH_BLOCK
            stop = min(start + BATCH_BLOCK, size)
            for k in range(products.shape[0]):
                row = products[k, start:stop]
                b = 0
                while b + 2 <= count:
                    s0 = retired if leave_retired[b, k] else ring
                    s1 = retired if leave_retired[b + 1, k] else ring
                    _slide_two(wide, row, retired[old_slots[b], start:stop], s0[leave_slots[b, k], start:stop],
                              ring[new_slots[b], start:stop], ring[lag_slots[b, k], start:stop],
                              retired[old_slots[b + 1], start:stop], s1[leave_slots[b + 1, k], start:stop],
                              ring[new_slots[b + 1], start:stop], ring[lag_slots[b + 1, k], start:stop])
                    b += 2
                while b < count:
                    source = retired if leave_retired[b, k] else ring
                    _slide_rows(wide, row, retired[old_slots[b], start:stop], source[leave_slots[b, k], start:stop],
                               ring[new_slots[b], start:stop], ring[lag_slots[b, k], start:stop])
                    b += 1

    return kernel


@functools.cache
def gd_kernel(remove: bool, parallel: bool = True) -> Callable[..., None]:
    """Generalized differences (BSLTL's gendiff.m), sliding window or tumbling block: Σ_{i<j}
    |I_i - I_j| over the window, exact int64, O(N) per pixel per push (every frame of the window
    is read; tumbling: the block's earlier frames, ``remove`` False).

    ``kernel(new, ring, old_slot, count, gd_sum)``: ring rows 0..``count``-1 hold the window's
    other frames; frame i (``new``) joins, so Σ_k |I_i - I_k| is added over them; with
    ``remove`` frame i-N (ring row ``old_slot``, skipped) leaves, and Σ_k |I_{i-N} - I_k| over
    the same rows is subtracted. Reads the ring only: the window kernel writes frame i after.
    Pixels go in blocks, rows along contiguous slices (the inner loop vectorises).
    """

    @kernel_variant(parallel)
    def kernel(new, ring, old_slot, count, gd_sum):  # pragma: no cover - compiled
        size = new.size
        blocks = (size + PRODUCTS_BLOCK - 1) // PRODUCTS_BLOCK
        for block in numba.prange(blocks):
            start = block * PRODUCTS_BLOCK
            stop = min(start + PRODUCTS_BLOCK, size)
            width = stop - start
            acc = np.zeros(width, np.int64)
            x = new[start:stop]
            old = ring[old_slot, start:stop]
            for k in range(count):
                if remove and k == old_slot:
                    continue
                row = ring[k, start:stop]
                for j in range(width):
                    v = np.int64(row[j])
                    if remove:
                        acc[j] += abs(np.int64(x[j]) - v) - abs(np.int64(old[j]) - v)
                    else:
                        acc[j] += abs(np.int64(x[j]) - v)
            for j in range(width):
                gd_sum[start + j] += acc[j]

    return kernel


@functools.cache
def dft_kernel(rotate: bool, parallel: bool = True) -> Callable[..., None]:
    """DFT bins of the frequency bands (:mod:`edgedsm.estimators.dft_bins`), O(B) per pixel.

    ``kernel(new, old, cos, sin, bins)``: d = new - old (exact in float64), then for each kept bin
    b with X = bins[0, b] + i·bins[1, b]: with ``rotate`` the sliding DFT's step X ← (X + d)·W,
    W = cos[b] + i·sin[b]; else the block sum X += d·(cos[b] - i·sin[b]). Pixels go in blocks,
    bins along contiguous rows (the inner loop vectorises).
    """

    @kernel_variant(parallel)
    def kernel(new, old, cos, sin, bins):  # pragma: no cover - compiled
        size = new.size
        count = cos.size
        blocks = (size + PRODUCTS_BLOCK - 1) // PRODUCTS_BLOCK
        for block in numba.prange(blocks):
            start = block * PRODUCTS_BLOCK
            stop = min(start + PRODUCTS_BLOCK, size)
            width = stop - start
            d = np.empty(width, np.float64)
            for j in range(width):
                d[j] = np.float64(new[start + j]) - np.float64(old[start + j])
            for b in range(count):
                c = cos[b]
                s = sin[b]
                re = bins[0, b, start:stop]
                im = bins[1, b, start:stop]
                for j in range(width):
                    if rotate:
                        a = re[j] + d[j]
                        y = im[j]
                        re[j] = c * a - s * y
                        im[j] = s * a + c * y
                    else:
                        re[j] = re[j] + d[j] * c
                        im[j] = im[j] - d[j] * s

    return kernel
