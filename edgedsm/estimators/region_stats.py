"""Region statistics straight from a window's sums: no float maps, no copy of the sums.

The daemon needs, per region and map, the pixel count, mean, standard deviation and 5/50/95 %
percentiles (:func:`edgedsm.analysis.region_stats`), and for the drying states only the activity
map's mean. Computing whole float maps first (:func:`edgedsm.estimators.snapshot.maps_from`)
writes 32 bytes per pixel and reads them back per region and map; here one fused pass over each
region's bounding box reads the engine's sums and evaluates each pixel's S1, S2 and S3 with the
arithmetic of the engine's maps kernel (``kernels_numba.maps_kernel``, Eq. 1-4; equality tested),
so it can run on the pipeline thread between two pushes, from the live sums (the pushes are on
that thread too), at about the cost of one push.

Per region and map (equal to ``maps_from`` + ``RegionBox.stats`` within 1e-12 relative, tested):

- the sample for percentiles is the same pixels as ``masked_moments`` takes (every k-th selected
  pixel in row-major order, k = ⌈pixels / samples⌉): their flat indices are fixed with the mask,
  found once (:class:`RegionPlan`), and the values there are computed exactly as the map's;
- mean and deviation come from one pass of sums shifted by the sample's mean c: Σ(x-c) and
  Σ(x-c)², compensated (Neumaier) per block of rows and over the blocks. With c within a few
  deviations of the mean, var = Σ(x-c)²/n - (Σ(x-c)/n)² loses nothing to cancellation, and one
  pass replaces the two a centred sum needs. Blocks are fixed by the box's shape (not by the
  thread count), so the result is the same whatever the threads.

Without numba (the optional extra ``fast``) the maps are computed from the sums and reduced by
:func:`edgedsm.analysis_kernels.masked_moments` (slower, same numbers).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from edgedsm.analysis import PERCENTILE_SAMPLES, RegionBox, RegionStats, percentiles
from edgedsm.analysis_kernels import masked_moments
from edgedsm.estimators.snapshot import EngineSnapshot, maps_from

#: Map names in the order of the kernels' outputs.
MAPS = ("s1", "s2", "s3")
#: Pixels per block of rows: one task of the parallel pass, and one compensated partial sum.
BLOCK_PIXELS = 1 << 16


@dataclass(frozen=True)
class RegionPlan:
    """A region prepared for :func:`region_moments` in an engine of ``shape``: its box and mask,
    and the flat indices (engine pixels) of the pixels its percentile sample takes."""

    box: RegionBox
    width: int  # the engine's row length, pixels
    pixels: int  # selected pixels
    sample_index: np.ndarray  # int64, every k-th selected pixel, row-major

    @classmethod
    def of(cls, box: RegionBox, shape: tuple[int, int], samples: int = PERCENTILE_SAMPLES) -> RegionPlan:
        selected = np.flatnonzero(box.mask)
        pixels = int(selected.size)
        stride = -(-pixels // samples)
        local = selected[::stride]
        box_width = box.cols.stop - box.cols.start
        rows, cols = np.divmod(local, box_width)
        index = (rows + box.rows.start) * shape[1] + cols + box.cols.start
        return cls(box, shape[1], pixels, np.ascontiguousarray(index, np.int64))


@dataclass(frozen=True)
class Moments:
    """One map over one region: pixel count, mean, standard deviation (units of the map) and the
    percentile sample (empty when only the mean was asked for)."""

    pixels: int
    mean: float
    std: float
    sample: np.ndarray

    def stats(self) -> RegionStats:
        """With the 5/50/95 % percentiles of the sample (as :func:`edgedsm.analysis.region_stats`)."""
        return RegionStats(self.pixels, self.mean, self.std, *percentiles(self.sample))


def region_moments(sums: EngineSnapshot, regions: Mapping[str, RegionPlan], maps: Sequence[str],
                   spread: bool = True, parallel: bool = True) -> dict[str, dict[str, Moments]]:
    """Moments of ``maps`` (among s1, s2, s3) over each region, from a window's sums.

    ``sums``: an engine snapshot, or the live sums (``SlidingWindow.snapshot(live=True)``; then on
    the thread that pushes, before the next push). Without ``spread`` only the means (std 0, no
    sample). ``parallel``: the pass over each box uses numba's threads (the caller's setting).
    """
    wanted = tuple(name for name in MAPS if name in maps)
    if sums.mode not in ("sliding", "tumbling", "exponential") or not wanted:
        raise ValueError(f"no region moments of {maps} for mode {sums.mode!r}")
    kernels = _kernels(*(name in wanted for name in MAPS), sums.mode == "exponential", parallel)
    if kernels is None:
        return _moments_from_maps(sums, regions, wanted, spread)
    block_sums, sample_values = kernels
    exponential = sums.mode == "exponential"
    arrays = sums.sums
    second = arrays["m2"] if exponential else arrays["total"]
    fourth = arrays["m2"] if exponential else arrays["total_sq"]
    common = (arrays["abs"], arrays["ratio"], second, fourth, sums.pairs, sums.ratio_unit, sums.window,
              sums.weight_frames)
    result: dict[str, dict[str, Moments]] = {}
    for name, plan in regions.items():
        box = plan.box
        if spread:
            sample = np.empty((len(MAPS), plan.sample_index.size))
            sample_values(*common, plan.sample_index, sample)
            shift = sample.mean(axis=1)
        else:
            sample = np.empty((len(MAPS), 0))
            shift = np.zeros(len(MAPS))
        box_width = box.cols.stop - box.cols.start
        block_rows = max(1, BLOCK_PIXELS // box_width)
        blocks = -(-(box.rows.stop - box.rows.start) // block_rows)
        partials = np.empty((blocks, len(MAPS), 4))
        block_sums(*common, plan.width, box.rows.start, box.cols.start, box.mask, block_rows, shift, partials)
        per_map = {}
        for k, key in enumerate(MAPS):
            if key not in wanted:
                continue
            first, squares = _combine(partials[:, k, 0], partials[:, k, 1]), _combine(partials[:, k, 2],
                                                                                        partials[:, k, 3])
            offset = first / plan.pixels
            mean = float(shift[k] + offset)
            std = float(np.sqrt(max(squares / plan.pixels - offset * offset, 0.0))) if spread else 0.0
            per_map[key] = Moments(plan.pixels, mean, std, sample[k] if spread else sample[k, :0])
        result[name] = per_map
    return result


def _combine(totals: np.ndarray, carries: np.ndarray) -> float:
    """Σ of the blocks' compensated partial sums (Neumaier over the totals, carries added)."""
    total, carry = 0.0, float(carries.sum())
    for x in totals.tolist():
        t = total + x
        carry += (total - t) + x if abs(total) >= abs(x) else (x - t) + total
        total = t
    return total + carry


def _moments_from_maps(sums: EngineSnapshot, regions: Mapping[str, RegionPlan], wanted: tuple[str, ...],
                       spread: bool) -> dict[str, dict[str, Moments]]:
    """Without numba: the float maps, reduced by masked_moments (same sample, same rounding class)."""
    values = maps_from(EngineSnapshot(**{**sums.__dict__, "estimators": wanted}))
    result: dict[str, dict[str, Moments]] = {}
    for name, plan in regions.items():
        box = plan.box
        per_map = {}
        for key in wanted:
            count, mean, std, sample = masked_moments(values[key][box.rows, box.cols], box.mask, PERCENTILE_SAMPLES)
            per_map[key] = Moments(count, mean, std if spread else 0.0, sample if spread else sample[:0])
        result[name] = per_map
    return result


@functools.cache
def _kernels(want_s1: bool, want_s2: bool, want_s3: bool, exponential: bool,
             parallel: bool) -> tuple[Callable[..., None], Callable[..., None]] | None:
    """The compiled (block sums, sample values) pair for one set of maps, or None without numba.

    The choices are compile-time constants (closure), as in the engine's kernels: no branch on
    them in the loops.
    """
    try:
        import numba
    except ImportError:  # numba is the optional 'fast' extra
        return None
    do_abs = want_s1 or want_s3

    @numba.njit(inline="always", nogil=True)
    def exponential_pixel(p, abs_sum, ratio_sum, second, weight):  # pragma: no cover - compiled
        """(S1, S2, S3) of flat pixel p from the exponential window's float means, as its maps."""
        value = 0.0
        s2 = 0.0
        s3 = 0.0
        if do_abs:
            value = abs_sum[p]
        if want_s2:
            s2 = ratio_sum[p]
        if want_s3:
            deviation = np.sqrt(second[p] / weight)
            s3 = value / deviation if deviation > 0.0 else 0.0
        return value, s2, s3

    @numba.njit(inline="always", nogil=True)
    def pixel(p, abs_sum, ratio_sum, second, fourth, pairs, ratio_unit, n, weight):  # pragma: no cover
        """(S1, S2, S3) of flat pixel p; the arithmetic of maps_kernel (window modes) or of the
        exponential maps: every operation as there, in the same order (the same float64)."""
        if exponential:
            return exponential_pixel(p, abs_sum, ratio_sum, second, weight)
        value = 0.0
        s2 = 0.0
        s3 = 0.0
        if do_abs:
            value = np.float64(abs_sum[p]) / pairs
        if want_s2:
            s2 = np.float64(ratio_sum[p]) * ratio_unit / pairs
        if want_s3:
            limit = np.int64(9223372036854775807) // n
            s = np.int64(second[p])
            k = np.int64(np.floor(np.float64(s) / n + 0.5))
            r = s - k * n
            centred = np.int64(fourth[p]) - k * (s + r)
            if centred <= limit:
                spread = np.float64(n * centred - r * r)
            else:
                spread = n * np.float64(centred) - np.float64(r * r)
            deviation = np.sqrt(spread) / n
            s3 = value / deviation if deviation > 0.0 else 0.0
        return value, s2, s3

    @numba.njit(inline="always", nogil=True)
    def add(total, carry, x):  # pragma: no cover - compiled
        t = total + x
        carry += (total - t) + x if abs(total) >= abs(x) else (x - t) + total
        return t, carry

    @numba.njit(nogil=True, cache=True)
    def sample_values(abs_sum, ratio_sum, second, fourth, pairs, ratio_unit, n, weight, index,
                      out):  # pragma: no cover - compiled
        for i in range(index.size):
            v1, v2, v3 = pixel(index[i], abs_sum, ratio_sum, second, fourth, pairs, ratio_unit, n, weight)
            out[0, i] = v1
            out[1, i] = v2
            out[2, i] = v3

    @numba.njit(inline="always", nogil=True)
    def pixel_fast(p, abs_sum, ratio_sum, second, fourth, inv_pairs, s2_unit, n, inv_n, s3_unit, limit,
                   weight):  # pragma: no cover - compiled
        """(S1, S2, S3) of flat pixel p within a few ulps of ``pixel``: products by reciprocals
        computed once (``inv_pairs`` = 1/(N-m), ``s2_unit`` = 2^-K/(N-m), ``s3_unit`` =
        N/(N-m), ``limit`` as in maps_kernel), one division and one square root per pixel instead
        of four and one, and no integer division. The
        centring integer k may differ from maps_kernel's by one: N²σ² is exact for every k."""
        if exponential:
            return exponential_pixel(p, abs_sum, ratio_sum, second, weight)
        value = 0.0
        s2 = 0.0
        s3 = 0.0
        if do_abs:
            value = np.float64(abs_sum[p]) * inv_pairs
        if want_s2:
            s2 = np.float64(ratio_sum[p]) * s2_unit
        if want_s3:
            s = np.int64(second[p])
            k = np.int64(np.floor(np.float64(s) * inv_n + 0.5))
            r = s - k * n
            centred = np.int64(fourth[p]) - k * (s + r)
            if centred <= limit:
                spread = np.float64(n * centred - r * r)
            else:
                spread = n * np.float64(centred) - np.float64(r * r)
            s3 = np.float64(abs_sum[p]) * s3_unit / np.sqrt(spread) if spread > 0.0 else 0.0
        return value, s2, s3

    @numba.njit(parallel=parallel, nogil=True, cache=True)
    def block_sums(abs_sum, ratio_sum, second, fourth, pairs, ratio_unit, n, weight, width, row0, col0, mask,
                   block_rows, shift, partials):  # pragma: no cover - compiled
        rows, cols = mask.shape
        c1, c2, c3 = shift[0], shift[1], shift[2]
        inv_pairs = 1.0 / pairs
        s2_unit = ratio_unit / pairs
        inv_n = 1.0 / n
        s3_unit = np.float64(n) / pairs
        limit = np.int64(9223372036854775807) // n
        for block in numba.prange(partials.shape[0]):
            t1 = e1 = q1 = f1 = 0.0
            t2 = e2 = q2 = f2 = 0.0
            t3 = e3 = q3 = f3 = 0.0
            for i in range(block * block_rows, min((block + 1) * block_rows, rows)):
                base = (row0 + i) * width + col0
                # plain sums along the row (no branch, independent chains), compensated across rows
                a1 = b1 = a2 = b2 = a3 = b3 = 0.0
                for j in range(cols):
                    if mask[i, j]:
                        v1, v2, v3 = pixel_fast(base + j, abs_sum, ratio_sum, second, fourth, inv_pairs, s2_unit,
                                                n, inv_n, s3_unit, limit, weight)
                        d1 = v1 - c1
                        d2 = v2 - c2
                        d3 = v3 - c3
                        a1 += d1
                        b1 += d1 * d1
                        a2 += d2
                        b2 += d2 * d2
                        a3 += d3
                        b3 += d3 * d3
                t1, e1 = add(t1, e1, a1)
                q1, f1 = add(q1, f1, b1)
                t2, e2 = add(t2, e2, a2)
                q2, f2 = add(q2, f2, b2)
                t3, e3 = add(t3, e3, a3)
                q3, f3 = add(q3, f3, b3)
            partials[block, 0, 0] = t1
            partials[block, 0, 1] = e1
            partials[block, 0, 2] = q1
            partials[block, 0, 3] = f1
            partials[block, 1, 0] = t2
            partials[block, 1, 1] = e2
            partials[block, 1, 2] = q2
            partials[block, 1, 3] = f2
            partials[block, 2, 0] = t3
            partials[block, 2, 1] = e3
            partials[block, 2, 2] = q3
            partials[block, 2, 3] = f3

    return block_sums, sample_values

