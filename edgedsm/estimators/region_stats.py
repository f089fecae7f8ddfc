"""Region statistics straight from a window's sums: no float maps, no copy of the sums.

The daemon needs, per region and map, the pixel count, mean, standard deviation and 5/50/95 %
percentiles (:func:`edgedsm.analysis.region_stats`), and for the drying states only the activity
map's mean. Computing whole float maps first (:func:`edgedsm.estimators.snapshot.maps_from`)
writes 32 bytes per pixel and reads them back per region and map; here one fused pass over the
rows the regions cover reads the engine's sums once, evaluates each covered pixel's S1, S2 and S3
once (however many regions hold it: :class:`RegionLayout`) into a row buffer, and reduces that
row per region. It runs on the pipeline thread between two pushes, from the live sums (the pushes
are on that thread too).

Per region and map (equal to ``maps_from`` + ``RegionBox.stats`` within 1e-12 relative, tested):

- the sample for percentiles is the same pixels as ``masked_moments`` takes (every k-th selected
  pixel in row-major order, k = ⌈pixels / samples⌉): their flat indices are fixed with the mask,
  found once (:class:`RegionPlan`), and the values there are computed exactly as the map's
  (the arithmetic of the engine's maps kernel, ``kernels_numba.maps_kernel``, Eq. 1-4);
- mean and deviation come from one pass of sums shifted by the sample's mean c: Σ(x-c) and
  Σ(x-c)². With c within a few deviations of the mean, var = Σ(x-c)²/n - (Σ(x-c)/n)² loses
  nothing to cancellation, and one pass replaces the two a centred sum needs. Along a row the
  sums run in vector lanes (reassociated: as accurate as in order); across rows they are
  compensated (Neumaier) per block of rows and over the blocks. Blocks are fixed by the covered
  rows (not by the thread count), so the result is the same whatever the threads.

Speed (what makes the pass vectorise): loops index views from 0 (a possibly negative index
costs a wrap-around check per element), the mask is a 0/1 factor rather than a branch, and when
ΣI² is stored as int32 (8-bit frames at any N, 12-bit ones up to N = 128) N²σ² = N·ΣI² - (ΣI)²
is evaluated in float64, where it is exact, instead of by the centred int64 arithmetic that
wider sums need.

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
class RegionLayout:
    """Regions laid out for one pass over the rows they cover: each pixel's maps are computed
    once, however many regions hold it (a whole-sensor region and one inside it cost one pass
    over the sensor, not 1.25).

    Rows split into bands where the set of regions crossing them changes; per band, the merged
    column intervals that some region covers are the pixels evaluated. Blocks of rows (the
    parallel tasks, and the compensated partial sums) are fixed by the covered rows and width,
    not by the thread count.
    """

    names: tuple[str, ...]
    plans: tuple[RegionPlan, ...]
    width: int  # the engine's row length, pixels
    boxes: np.ndarray  # int64 (regions, 4): first row, row past the last, first column, column past the last
    masks: np.ndarray  # uint8, the masks of the regions that are not full boxes, concatenated
    mask_first: np.ndarray  # int64 (regions,): where each region's mask starts in ``masks`` (-1: full box)
    band_rows: np.ndarray  # int64 (bands + 1,): the first row of each band, and the row past the last
    band_first: np.ndarray  # int64 (bands + 1,): each band's first interval in ``intervals``
    intervals: np.ndarray  # int64 (intervals, 2): first column, column past the last
    block_rows: int

    @classmethod
    def of(cls, plans: Mapping[str, RegionPlan]) -> RegionLayout:
        if not plans:
            raise ValueError("no regions to lay out")
        names, ordered = tuple(plans), tuple(plans.values())
        width = ordered[0].width
        boxes = np.array([(p.box.rows.start, p.box.rows.stop, p.box.cols.start, p.box.cols.stop) for p in ordered],
                         np.int64).reshape(-1, 4)
        first, parts, at = [], [], 0
        for plan in ordered:
            if plan.box.mask.all():
                first.append(-1)
                continue
            first.append(at)
            parts.append(plan.box.mask.astype(np.uint8).ravel())
            at += parts[-1].size
        cuts = sorted({int(v) for v in boxes[:, 0]} | {int(v) for v in boxes[:, 1]})
        band_rows, band_first, intervals = [], [0], []
        for top in cuts[:-1]:
            crossing = sorted((int(b[2]), int(b[3])) for b in boxes if b[0] <= top < b[1])
            merged: list[list[int]] = []
            for start, stop in crossing:
                if merged and start <= merged[-1][1]:
                    merged[-1][1] = max(merged[-1][1], stop)
                else:
                    merged.append([start, stop])
            band_rows.append(top)
            intervals.extend(merged)
            band_first.append(len(intervals))
        band_rows.append(cuts[-1])
        covered_width = int(boxes[:, 3].max() - boxes[:, 2].min())
        return cls(names, ordered, width, boxes,
                   np.concatenate(parts) if parts else np.zeros(1, np.uint8), np.array(first, np.int64),
                   np.array(band_rows, np.int64), np.array(band_first, np.int64),
                   np.array(intervals, np.int64).reshape(-1, 2), max(1, BLOCK_PIXELS // covered_width))

    @property
    def blocks(self) -> int:
        return -(-int(self.band_rows[-1] - self.band_rows[0]) // self.block_rows)


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


def region_moments(sums: EngineSnapshot, regions: RegionLayout | Mapping[str, RegionPlan], maps: Sequence[str],
                   spread: bool = True, parallel: bool = True) -> dict[str, dict[str, Moments]]:
    """Moments of ``maps`` (among s1, s2, s3) over each region, from a window's sums.

    ``sums``: an engine snapshot, or the live sums (``SlidingWindow.snapshot(live=True)``; then on
    the thread that pushes, before the next push). ``regions``: best laid out once
    (:meth:`RegionLayout.of`). Without ``spread`` only the means (std 0, no sample).
    ``parallel``: the pass uses numba's threads (the caller's setting).
    """
    wanted = tuple(name for name in MAPS if name in maps)
    if sums.mode not in ("sliding", "tumbling", "exponential") or not wanted:
        raise ValueError(f"no region moments of {maps} for mode {sums.mode!r}")
    if not regions:
        return {}
    layout = regions if isinstance(regions, RegionLayout) else RegionLayout.of(regions)
    exponential = sums.mode == "exponential"
    kernels = _kernels(*(name in wanted for name in MAPS), exponential, parallel,
                       not exponential and _direct_spread(sums), spread)
    if kernels is None:
        return _moments_from_maps(sums, dict(zip(layout.names, layout.plans, strict=True)), wanted, spread)
    region_pass, sample_values = kernels
    arrays = sums.sums
    second = arrays["m2"] if exponential else arrays["total"]
    fourth = arrays["m2"] if exponential else arrays["total_sq"]
    common = (arrays["abs"], arrays["ratio"], second, fourth, sums.pairs, sums.ratio_unit, sums.window,
              sums.weight_frames)
    count = len(layout.names)
    samples: list[np.ndarray] = []
    shifts = np.zeros((count, len(MAPS)))
    for r, plan in enumerate(layout.plans):
        if spread:
            sample = np.empty((len(MAPS), plan.sample_index.size))
            sample_values(*common, plan.sample_index, sample)
            shifts[r] = sample.mean(axis=1)
        else:
            sample = np.empty((len(MAPS), 0))
        samples.append(sample)
    partials = np.empty((layout.blocks, count, len(MAPS), 4))
    region_pass(*common, layout.width, layout.block_rows, layout.band_rows, layout.band_first, layout.intervals,
                layout.boxes, layout.masks, layout.mask_first, shifts, partials)
    result: dict[str, dict[str, Moments]] = {}
    for r, (name, plan) in enumerate(zip(layout.names, layout.plans, strict=True)):
        per_map = {}
        for k, key in enumerate(MAPS):
            if key not in wanted:
                continue
            first = _combine(partials[:, r, k, 0], partials[:, r, k, 1])
            squares = _combine(partials[:, r, k, 2], partials[:, r, k, 3])
            offset = first / plan.pixels
            mean = float(shifts[r, k] + offset)
            std = float(np.sqrt(max(squares / plan.pixels - offset * offset, 0.0))) if spread else 0.0
            per_map[key] = Moments(plan.pixels, mean, std, samples[r][k])
        result[name] = per_map
    return result


def _direct_spread(sums: EngineSnapshot) -> bool:
    """N²σ² = N·ΣI² - (ΣI)² is exact in float64 for these sums: N·ΣI² is below 2^53 whatever the
    frames when ΣI² is stored as int32 (N <= 100 000), and (ΣI)² <= N·ΣI² (Cauchy-Schwarz)."""
    return sums.window * float(np.iinfo(sums.sums["total_sq"].dtype).max) < 2.0**53


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
def _kernels(want_s1: bool, want_s2: bool, want_s3: bool, exponential: bool, parallel: bool,
             direct: bool = False, spread: bool = True) -> tuple[Callable[..., None], Callable[..., None]] | None:
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
            if direct:  # the same N²σ² as the centred integers below: exact (see _direct_spread)
                s_float = np.float64(second[p])
                spread = n * np.float64(fourth[p]) - s_float * s_float
            else:
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

    @numba.njit(parallel=parallel, nogil=True, cache=True)
    def sample_values(abs_sum, ratio_sum, second, fourth, pairs, ratio_unit, n, weight, index,
                      out):  # pragma: no cover - compiled
        for i in numba.prange(index.size):
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
            if direct:  # N·ΣI² and (ΣI)² below 2^53: both exact in float64, and so their difference
                s_float = np.float64(second[p])
                spread = n * np.float64(fourth[p]) - s_float * s_float
            else:
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

    @numba.njit(nogil=True, inline="always")
    def row_values(abs_sum, ratio_sum, second, fourth, first, values, inv_pairs, s2_unit, n, inv_n, s3_unit, limit,
                   weight):  # pragma: no cover - compiled
        """The maps of flat pixels first, first+1, ... into the columns of ``values`` (3, count).
        Element-wise from index 0 over views: the loop vectorises (an index that might be negative
        would not)."""
        for j in range(values.shape[1]):
            v1, v2, v3 = pixel_fast(first + j, abs_sum, ratio_sum, second, fourth, inv_pairs, s2_unit, n, inv_n,
                                    s3_unit, limit, weight)
            if do_abs:
                values[0, j] = v1
            if want_s2:
                values[1, j] = v2
            if want_s3:
                values[2, j] = v3

    # Reassociation lets the row's plain sums run in vector lanes (the row's sum in another order,
    # as accurate); the compensated sums across rows are in the strict caller.
    @numba.njit(nogil=True, fastmath={"reassoc", "nsz"})
    def row_moments(values, mask, full, shift):  # pragma: no cover - compiled
        """Σ(x-c) and Σ(x-c)² of each map over the columns of ``values`` (3, count) where ``mask``
        (uint8, count) selects, or over all of them when ``full``."""
        c1, c2, c3 = shift[0], shift[1], shift[2]
        a1 = b1 = a2 = b2 = a3 = b3 = 0.0
        if full:
            for j in range(values.shape[1]):
                if want_s1:
                    d1 = values[0, j] - c1
                    a1 += d1
                    if spread:
                        b1 += d1 * d1
                if want_s2:
                    d2 = values[1, j] - c2
                    a2 += d2
                    if spread:
                        b2 += d2 * d2
                if want_s3:
                    d3 = values[2, j] - c3
                    a3 += d3
                    if spread:
                        b3 += d3 * d3
        else:
            for j in range(values.shape[1]):
                w = np.float64(mask[j])  # 0 or 1: a product, not a branch
                if want_s1:
                    d1 = (values[0, j] - c1) * w
                    a1 += d1
                    if spread:
                        b1 += d1 * d1
                if want_s2:
                    d2 = (values[1, j] - c2) * w
                    a2 += d2
                    if spread:
                        b2 += d2 * d2
                if want_s3:
                    d3 = (values[2, j] - c3) * w
                    a3 += d3
                    if spread:
                        b3 += d3 * d3
        return a1, b1, a2, b2, a3, b3

    @numba.njit(parallel=parallel, nogil=True, cache=True)
    def region_pass(abs_sum, ratio_sum, second, fourth, pairs, ratio_unit, n, weight, width, block_rows, band_rows,
                    band_first, intervals, boxes, masks, mask_first, shifts, partials):  # pragma: no cover
        inv_pairs = 1.0 / pairs
        s2_unit = ratio_unit / pairs
        inv_n = 1.0 / n
        s3_unit = np.float64(n) / pairs
        limit = np.int64(9223372036854775807) // n
        first_row = band_rows[0]
        last_row = band_rows[band_rows.size - 1]
        regions = boxes.shape[0]
        for block in numba.prange(partials.shape[0]):
            values = np.zeros((3, width))
            sums = np.zeros((regions, 3, 4))  # per region and map: Σ, its carry, Σ², its carry
            band = 0
            for i in range(first_row + block * block_rows, min(first_row + (block + 1) * block_rows, last_row)):
                while band_rows[band + 1] <= i:
                    band += 1
                base = i * width
                for k in range(band_first[band], band_first[band + 1]):
                    start, stop = intervals[k, 0], intervals[k, 1]
                    row_values(abs_sum, ratio_sum, second, fourth, base + start, values[:, start:stop], inv_pairs,
                               s2_unit, n, inv_n, s3_unit, limit, weight)
                for r in range(regions):
                    if boxes[r, 0] <= i < boxes[r, 1]:
                        start, stop = boxes[r, 2], boxes[r, 3]
                        at = mask_first[r] + (i - boxes[r, 0]) * (stop - start)  # unused for a full box
                        full = mask_first[r] < 0
                        row = row_moments(values[:, start:stop], masks[at:at + stop - start] if not full else masks[:0],
                                          full, shifts[r])
                        for m in range(3):
                            sums[r, m, 0], sums[r, m, 1] = add(sums[r, m, 0], sums[r, m, 1], row[2 * m])
                            sums[r, m, 2], sums[r, m, 3] = add(sums[r, m, 2], sums[r, m, 3], row[2 * m + 1])
            partials[block] = sums

    return region_pass, sample_values

