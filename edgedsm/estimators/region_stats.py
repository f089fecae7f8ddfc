"""Region statistics straight from a window's sums: no float maps, no copy of the sums.

The daemon needs, per region and map, the pixel count, mean, standard deviation and 5/50/95 %
percentiles (:func:`edgedsm.estimators.region_box.region_stats`), and for the drying states only the activity
map's mean. Computing whole float maps first (:func:`edgedsm.estimators.snapshot.maps_from`)
writes 32 bytes per pixel and reads them back per region and map. Here one pass over the rows
the regions cover (:class:`RegionLayout`) reads the engine's sums once: each pixel of the
regions' union gets its S1, S2 and S3 (Eq. 1-4), and the contrast, Fujii and IM asked for
(:data:`MAPS`), computed once into a row buffer, whatever the
regions holding it, and each region sums its column runs of that buffer. GD (generalized
differences), one division of its own exact sum per pixel, is formed over each region's box and
reduced apart (:func:`region_moments`). It runs on the
pipeline thread between two pushes, from the live sums (the pushes are on that thread too).

Per region and map (equal to ``maps_from`` + ``RegionBox.stats`` within 1e-12 relative, tested):

- the sample for percentiles is the same pixels as ``masked_moments`` takes (every k-th selected
  pixel in row-major order, k = ⌈pixels / samples⌉): their flat indices are fixed with the mask,
  found once (:class:`RegionPlan`), and their values are computed in the same pass, while their
  rows are in cache;
- mean and deviation come from one pass of sums shifted by c, the mean of every 256th pixel of
  the sample (gathered before the pass): Σ(x-c) and Σ(x-c)². With c within a few deviations of
  the mean, var = Σ(x-c)²/n - (Σ(x-c)/n)² loses nothing to cancellation, and one pass replaces
  the two a centred sum needs. The sums along a row run in vector lanes (reassociated: a few
  ulps), rows are added with Neumaier compensation per block of rows and the blocks likewise.
  Blocks are fixed by the layout (not by the thread count), so the result is the same whatever
  the threads.

Every pixel's values (row buffers and samples alike) is formed by the one definition the
engine's maps use, :func:`edgedsm.estimators.activity.pixel_values`: bit for bit the map's value.

The kernels are module-level functions, or closures over plain constants only, so numba's disk
cache finds them again in the next process (a closure over another compiled closure gets a new
cache key in every process: seconds of compiling at every start).

Without numba (the optional extra ``fast``) the maps are computed from the sums and reduced by
:func:`edgedsm.estimators.masked_moments.masked_moments` (slower, same numbers).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from edgedsm.estimators.activity import pixel_values
from edgedsm.estimators.dft_bins import BAND_NAMES
from edgedsm.estimators.jit import kernel_variant
from edgedsm.estimators.masked_moments import masked_moments
from edgedsm.estimators.region_box import PERCENTILE_SAMPLES, RegionBox, RegionStats, percentiles
from edgedsm.estimators.registry import PAIR_SUM, VALUES, KernelSpec, names
from edgedsm.estimators.snapshot import EngineSnapshot, maps_from
from edgedsm.estimators.value_set import gd_of_sum

try:
    import numba
except ImportError:  # numba is the optional 'fast' extra
    numba = None

#: Map names in the order of the kernels' outputs: the fused pass's values that are maps (the
#: registry's VALUES but σ).
MAPS = tuple(name for name in VALUES if name != "sigma")
#: Pixels per block of rows: one task of the parallel pass, and one compensated partial sum.
BLOCK_PIXELS = 1 << 16
#: The shift c of the one-pass sums is the mean of every SHIFT_STRIDE-th pixel of the sample.
SHIFT_STRIDE = 256


def mask_runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Row, first column and end column (exclusive) of each horizontal run of True in ``mask``
    (int64, row-major order)."""
    height, width = mask.shape
    padded = np.zeros((height, width + 2), np.int8)
    padded[:, 1:-1] = mask
    steps = np.diff(padded, axis=1)
    rows, starts = np.nonzero(steps == 1)
    _, stops = np.nonzero(steps == -1)
    return rows.astype(np.int64), starts.astype(np.int64), stops.astype(np.int64)


@dataclass(frozen=True)
class RegionPlan:
    """A region prepared for :func:`region_moments` in an engine of ``shape``: its box and mask,
    its column runs and the flat indices (engine pixels) of the pixels its percentile sample
    takes."""

    box: RegionBox
    width: int  # the engine's row length, pixels
    pixels: int  # selected pixels
    sample_index: np.ndarray  # int64, every k-th selected pixel, row-major
    runs: np.ndarray  # int64 (k, 3): engine row, first column, end column of each run of pixels

    @property
    def shift_index(self) -> np.ndarray:
        """The pixels whose mean is the shift c of the one-pass sums (every SHIFT_STRIDE-th of
        the sample)."""
        return np.ascontiguousarray(self.sample_index[::SHIFT_STRIDE])

    @classmethod
    def of(cls, box: RegionBox, shape: tuple[int, int], samples: int = PERCENTILE_SAMPLES) -> RegionPlan:
        selected = np.flatnonzero(box.mask)
        pixels = int(selected.size)
        stride = -(-pixels // samples)
        local = selected[::stride]
        box_width = box.cols.stop - box.cols.start
        rows, cols = np.divmod(local, box_width)
        index = (rows + box.rows.start) * shape[1] + cols + box.cols.start
        run_rows, starts, stops = mask_runs(box.mask)
        runs = np.stack([run_rows + box.rows.start, starts + box.cols.start, stops + box.cols.start], axis=1)
        return cls(box, shape[1], pixels, np.ascontiguousarray(index, np.int64), np.ascontiguousarray(runs))


@dataclass(frozen=True)
class RegionLayout:
    """Regions of one engine prepared for one pass: the band of rows they cover and, per row
    (relative to ``row0``), the merged column runs of their union (``cover``) and each region's
    own runs (``runs``), columns relative to ``col0``. Build it once per set of regions."""

    plans: dict[str, RegionPlan]
    width: int
    row0: int
    col0: int
    cols: int  # the union's bounding-box width
    cover_ptr: np.ndarray  # int64 (rows+1,): row i's merged runs are cover[cover_ptr[i]:cover_ptr[i+1]]
    cover: np.ndarray  # int64 (k, 2): first and end column
    run_ptr: np.ndarray  # int64 (regions, rows+1): region r's runs on row i, as cover_ptr
    runs: np.ndarray  # int64 (m, 2)
    sample_ptr: np.ndarray  # int64 (regions, rows+1): region r's sample pixels on row i, as run_ptr
    sample_index: np.ndarray  # int64: the regions' sample pixels (flat engine indices), one after another
    shift_index: tuple[np.ndarray, ...]  # per region, RegionPlan.shift_index

    @property
    def rows(self) -> int:
        return self.cover_ptr.size - 1

    @classmethod
    def of(cls, plans: Mapping[str, RegionPlan]) -> RegionLayout:
        plans = dict(plans)
        widths = {plan.width for plan in plans.values()}
        if len(widths) > 1:
            raise ValueError(f"regions of engines of different widths {sorted(widths)}")
        width = widths.pop() if widths else 0
        every = np.concatenate([plan.runs for plan in plans.values()]) if plans else np.zeros((0, 3), np.int64)
        if every.shape[0] == 0:
            empty = np.zeros((0, 2), np.int64)
            none = np.zeros((len(plans), 1), np.int64)
            return cls(plans, width, 0, 0, 0, np.zeros(1, np.int64), empty, none, empty, none,
                       np.zeros(0, np.int64), tuple(plan.shift_index for plan in plans.values()))
        row0, col0 = int(every[:, 0].min()), int(every[:, 1].min())
        rows, cols = int(every[:, 0].max()) + 1 - row0, int(every[:, 2].max()) - col0
        lines = np.arange(rows + 1)
        run_ptr = np.empty((len(plans), rows + 1), np.int64)
        sample_ptr = np.empty((len(plans), rows + 1), np.int64)
        offset = sampled = 0
        for r, plan in enumerate(plans.values()):
            run_ptr[r] = offset + np.searchsorted(plan.runs[:, 0] - row0, lines)
            offset += plan.runs.shape[0]
            sample_ptr[r] = sampled + np.searchsorted(plan.sample_index // width - row0, lines)
            sampled += plan.sample_index.size
        runs = every[:, 1:] - col0
        # the union: runs in (row, start) order, merged where one starts before the reach of
        # the ones before it on its row (keys row·(W+1)+column keep rows apart)
        order = np.lexsort((every[:, 1], every[:, 0]))
        rel_rows, starts, stops = every[order, 0] - row0, every[order, 1] - col0, every[order, 2] - col0
        base = rel_rows * (width + 1)
        reach = np.maximum.accumulate(base + stops)
        first = np.ones(order.size, bool)
        first[1:] = base[1:] + starts[1:] > reach[:-1]
        heads = np.flatnonzero(first)
        ends = np.maximum.reduceat(base + stops, heads) - base[heads]
        cover = np.stack([starts[heads], ends], axis=1)
        cover_ptr = np.searchsorted(rel_rows[heads], lines).astype(np.int64)
        sample_index = np.concatenate([plan.sample_index for plan in plans.values()]).astype(np.int64)
        return cls(plans, width, row0, col0, cols, cover_ptr, np.ascontiguousarray(cover, np.int64), run_ptr,
                   np.ascontiguousarray(runs, np.int64), sample_ptr, sample_index,
                   tuple(plan.shift_index for plan in plans.values()))


@dataclass(frozen=True)
class Moments:
    """One map over one region: pixel count, mean, standard deviation (units of the map) and the
    percentile sample (empty when only the mean was asked for)."""

    pixels: int
    mean: float
    std: float
    sample: np.ndarray

    def stats(self) -> RegionStats:
        """With the 5/50/95 % percentiles of the sample (as :func:`edgedsm.estimators.region_box.region_stats`)."""
        return RegionStats(self.pixels, self.mean, self.std, *percentiles(self.sample))


def region_moments(sums: EngineSnapshot, regions: Mapping[str, RegionPlan] | RegionLayout, maps: Sequence[str],
                   spread: bool = True, parallel: bool = True) -> dict[str, dict[str, Moments]]:
    """Moments of ``maps`` (every streamed map of the registry but τc) over each region, from a window's sums.

    ``sums``: an engine snapshot, or the live sums (``SlidingWindow.snapshot(live=True)``; then on
    the thread that pushes, before the next push). ``regions``: plans by name, or their
    :class:`RegionLayout` (built once: cheaper per call). Without ``spread`` only the means (std
    0, no sample). ``parallel``: the pass uses numba's threads (the caller's setting).
    GD (generalized differences) is not in the fused pass (its per-pixel value is one division of
    its own exact sum, :func:`~edgedsm.estimators.value_set.gd_of_sum`): its values over each
    region's box are formed and reduced as without numba (same sample, same rounding class). Nor
    are the frequency bands (their values come from B DFT bins per pixel): each region's box is
    formed by the engine's band maps and reduced likewise. A registry map "derived" from the fused
    pass's values is formed over the whole frame (:func:`~edgedsm.estimators.snapshot.maps_from`)
    and reduced over each region's box likewise.
    """
    wanted = tuple(name for name in MAPS if name in maps)
    bands = tuple(name for name in BAND_NAMES if name in maps)
    derived = tuple(name for name in names(source="derived") if name in maps)
    if sums.mode not in ("sliding", "tumbling", "exponential") or not (wanted or PAIR_SUM in maps or bands
                                                                           or derived):
        raise ValueError(f"no region moments of {maps} for mode {sums.mode!r}")
    layout = regions if isinstance(regions, RegionLayout) else RegionLayout.of(regions)
    result = _fused_moments(sums, layout, wanted, spread, parallel) if wanted else {name: {} for name in layout.plans}
    if derived:
        if unknown := [name for name in derived if name not in sums.estimators]:
            raise ValueError(f"the snapshot carries no sums of {unknown}")
        whole = maps_from(sums)
        for name, plan in layout.plans.items():
            for key in derived:
                result[name][key] = _box_moments(whole[key][plan.box.rows, plan.box.cols], plan.box, spread)
    if PAIR_SUM in maps:
        gd_sums = sums.sums[PAIR_SUM].reshape(sums.shape)
        for name, plan in layout.plans.items():
            box = plan.box
            result[name][PAIR_SUM] = _box_moments(gd_of_sum(gd_sums[box.rows, box.cols], sums.window), box, spread)
    if bands:  # from the DFT bins and σ² of each region's box (dft_bins.DftBins.maps)
        assert sums.bands is not None, "a snapshot of the bands carries their maps function"
        height, width = sums.shape
        bins, total, total_sq = sums.sums["bins"], sums.sums["total"], sums.sums["total_sq"]
        for name, plan in layout.plans.items():
            box = plan.box
            part = {"bins": bins.reshape(2, -1, height, width)[:, :, box.rows, box.cols],  # views: no copy
                    "total": total.reshape(height, width)[box.rows, box.cols],
                    "total_sq": total_sq.reshape(height, width)[box.rows, box.cols]}
            for key, values in sums.bands(part, bands).items():
                result[name][key] = _box_moments(values, box, spread)
    return result


def _fused_moments(sums: EngineSnapshot, layout: RegionLayout, wanted: tuple[str, ...], spread: bool,
                   parallel: bool) -> dict[str, dict[str, Moments]]:
    """:func:`region_moments` of ``wanted`` (:data:`MAPS` order) by the fused pass over the sums."""
    kind = "exponential" if sums.mode == "exponential" else "window"
    want = [name in wanted for name in MAPS]
    kernels = _kernels(*want[:3], kind, parallel, *want[3:])
    if kernels is None:
        return _moments_from_maps(sums, layout.plans, wanted, spread)
    block_sums, sample_values = kernels
    common = (*sums.value_inputs, sums.pairs, sums.ratio_unit, sums.window, sums.weight_frames)
    count = len(layout.plans)
    shift = np.zeros((count, len(MAPS)))
    if spread:
        for r, index in enumerate(layout.shift_index):
            some = np.empty((len(MAPS), index.size))
            sample_values(*common, index, some)
            shift[r] = some.mean(axis=1)
    samples = np.empty((len(MAPS), layout.sample_index.size if spread else 0))
    block_rows = max(1, BLOCK_PIXELS // max(layout.cols, 1))
    blocks = -(-layout.rows // block_rows)
    partials = np.zeros((blocks, count, len(MAPS), 4))
    block_sums(*common, layout.width, layout.row0, layout.col0, layout.cols, block_rows, layout.cover_ptr,
               layout.cover, layout.run_ptr, layout.runs, shift, partials, spread, layout.sample_ptr,
               layout.sample_index, samples)
    result: dict[str, dict[str, Moments]] = {}
    ends = np.cumsum([0] + [plan.sample_index.size if spread else 0 for plan in layout.plans.values()])
    for r, (name, plan) in enumerate(layout.plans.items()):
        per_map = {}
        for k, key in enumerate(MAPS):
            if key not in wanted:
                continue
            first = _combine(partials[:, r, k, 0], partials[:, r, k, 1])
            squares = _combine(partials[:, r, k, 2], partials[:, r, k, 3])
            offset = first / plan.pixels
            mean = float(shift[r, k] + offset)
            std = float(np.sqrt(max(squares / plan.pixels - offset * offset, 0.0))) if spread else 0.0
            per_map[key] = Moments(plan.pixels, mean, std, samples[k, ends[r]:ends[r + 1]])
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
    values = maps_from(sums)  # all the snapshot's maps: its maps kernel was chosen for them
    return {name: {key: _box_moments(values[key][plan.box.rows, plan.box.cols], plan.box, spread) for key in wanted}
            for name, plan in regions.items()}


def _box_moments(values: np.ndarray, box: RegionBox, spread: bool) -> Moments:
    """A map's ``values`` over a region's box, reduced by masked_moments where its mask is set."""
    count, mean, std, sample = masked_moments(values, box.mask, PERCENTILE_SAMPLES)
    return Moments(count, mean, std if spread else 0.0, sample if spread else sample[:0])


# -- compiled kernels (numba) ---------------------------------------------------------------------
# Module-level functions (found again by numba's disk cache); the map choices are arguments that
# the closures of _kernels pass as constants, so the branches on them fold away.

if numba is not None:

    @numba.njit(inline="always", nogil=True, cache=True)
    def _store(out, j, v1, v2, v3, vc, vf, vi, want_s1, do_s2, do_s3, do_contrast, do_fujii,
               do_im):  # pragma: no cover - compiled
        """A pixel's values into column ``j`` of ``out`` (rows in the order of MAPS)."""
        if want_s1:
            out[0, j] = v1
        if do_s2:
            out[1, j] = v2
        if do_s3:
            out[2, j] = v3
        if do_contrast:
            out[3, j] = vc
        if do_fujii:
            out[4, j] = vf
        if do_im:
            out[5, j] = vi

    @numba.njit(inline="always", nogil=True, cache=True)
    def _row_values(exponential, do_abs, do_s2, do_s3, do_contrast, do_fujii, do_im, size, abs_sum, ratio_sum,
                    second, fourth, sq_sum, out1, out2, out3, out4, out5, out6, pairs, ratio_unit, n,
                    weight):  # pragma: no cover - compiled
        """One run of a row (views starting at index 0): the values into out1..6 (MAPS order),
        each pixel's values as the maps kernel forms them
        (:func:`edgedsm.estimators.activity.pixel_values`). One 1-D array per map: the loop
        vectorises (rows of one 2-D buffer made the region statistics 1.8x slower)."""
        for j in range(size):
            v1, v2, v3, _, vc, vf, vi = pixel_values(exponential, do_abs, do_s2, do_s3, do_contrast, do_fujii, do_im,
                                                     j, abs_sum, ratio_sum, second, fourth, sq_sum, pairs, ratio_unit,
                                                     n, weight)
            if do_abs:
                out1[j] = v1
            if do_s2:
                out2[j] = v2
            if do_s3:
                out3[j] = v3
            if do_contrast:
                out4[j] = vc
            if do_fujii:
                out5[j] = vf
            if do_im:
                out6[j] = vi

    @numba.njit(nogil=True, fastmath={"reassoc", "nsz"}, cache=True)
    def _run_moments(values, shift):  # pragma: no cover - compiled
        """Σ(x-c) and Σ(x-c)² of a run (reassociated: the loop runs in vector lanes)."""
        first = 0.0
        squares = 0.0
        for j in range(values.size):
            d = values[j] - shift
            first += d
            squares += d * d
        return first, squares

    @numba.njit(inline="always", nogil=True, cache=True)
    def _neumaier(partials, block, r, k, slot, x):  # pragma: no cover - compiled
        """Add x to the compensated partial (total at ``slot``, carry at ``slot`` + 1)."""
        total = partials[block, r, k, slot]
        t = total + x
        if abs(total) >= abs(x):
            partials[block, r, k, slot + 1] += (total - t) + x
        else:
            partials[block, r, k, slot + 1] += (x - t) + total
        partials[block, r, k, slot] = t

    @numba.njit(inline="always", nogil=True, cache=True)
    def _region_row(values, k, r, i, run_ptr, runs, shift, partials, block):  # pragma: no cover - compiled
        """Region r's runs on row i of the row buffer ``values`` (map k), into the block's partials."""
        if run_ptr[r, i + 1] == run_ptr[r, i]:
            return
        first = 0.0
        squares = 0.0
        for q in range(run_ptr[r, i], run_ptr[r, i + 1]):
            a, b = _run_moments(values[runs[q, 0]:runs[q, 1]], shift[r, k])
            first += a
            squares += b
        _neumaier(partials, block, r, k, 0, first)
        _neumaier(partials, block, r, k, 2, squares)


@functools.cache
def _kernels(want_s1: bool, want_s2: bool, want_s3: bool, kind: str, parallel: bool, want_contrast: bool = False,
             want_fujii: bool = False, want_im: bool = False) -> tuple[Callable[..., None], Callable[..., None]] | None:
    """The compiled (block sums, sample values) pair for one set of maps (MAPS order) and one
    ``kind`` of sums ("window": integer sums; "exponential": weighted means), or None without
    numba. The choices are compile-time constants (closure over plain values only, so the disk
    cache finds it)."""
    if numba is None:
        return None
    want = (want_s1, want_s2, want_s3, want_contrast, want_fujii, want_im)
    spec = KernelSpec.of([name for name, on in zip(MAPS, want, strict=True) if on])
    do_abs, do_s2, do_s3, do_contrast, do_fujii, do_im = spec.flags
    exponential = kind == "exponential"

    @kernel_variant(parallel)
    def sample_values(abs_sum, ratio_sum, second, fourth, sq_sum, pairs, ratio_unit, n, weight, index,
                      out):  # pragma: no cover - compiled
        for i in numba.prange(index.size):
            v1, v2, v3, _, vc, vf, vi = pixel_values(exponential, do_abs, do_s2, do_s3, do_contrast, do_fujii, do_im,
                                                     index[i], abs_sum, ratio_sum, second, fourth, sq_sum, pairs,
                                                     ratio_unit, n, weight)
            _store(out, i, v1, v2, v3, vc, vf, vi, True, True, True, True, True, True)

    @kernel_variant(parallel)
    def block_sums(abs_sum, ratio_sum, second, fourth, sq_sum, pairs, ratio_unit, n, weight, width, row0, col0, cols,
                   block_rows, cover_ptr, cover, run_ptr, runs, shift, partials, spread, sample_ptr, sample_index,
                   samples):  # pragma: no cover - compiled
        """Per block of rows (in parallel): the union's values into row buffers, each region's runs
        summed, and with ``spread`` the exact values of the sample pixels on these rows (in cache
        now). ``do_*``: activity.pixel_values' flags; S2 is summed with ``do_s2`` (Fujii's maps
        alone sum S2 too, unread), S1 with ``want_s1``. Written out here rather than inlined from
        a helper: numba copies an inlined function's IR block by block with its whole scope, in
        time that grows with blocks × variables, and this body was most of every variant's
        compile time (docs/engine.md)."""
        for block in numba.prange(partials.shape[0]):
            buffer1 = np.empty(cols if do_abs else 0)
            buffer2 = np.empty(cols if do_s2 else 0)
            buffer3 = np.empty(cols if do_s3 else 0)
            buffer4 = np.empty(cols if do_contrast else 0)
            buffer5 = np.empty(cols if do_fujii else 0)
            buffer6 = np.empty(cols if do_im else 0)
            rows = cover_ptr.size - 1
            for i in range(block * block_rows, min((block + 1) * block_rows, rows)):
                base = (row0 + i) * width + col0
                for c in range(cover_ptr[i], cover_ptr[i + 1]):
                    start, stop = cover[c, 0], cover[c, 1]
                    first, last = base + start, base + stop
                    _row_values(exponential, do_abs, do_s2, do_s3, do_contrast, do_fujii, do_im, stop - start,
                                abs_sum[first:last] if do_abs else abs_sum,
                                ratio_sum[first:last] if do_s2 else ratio_sum,
                                second[first:last] if do_s3 or do_contrast else second,
                                fourth[first:last] if do_s3 or do_contrast else fourth,
                                sq_sum[first:last] if do_im else sq_sum, buffer1[start:stop] if do_abs else buffer1,
                                buffer2[start:stop] if do_s2 else buffer2, buffer3[start:stop] if do_s3 else buffer3,
                                buffer4[start:stop] if do_contrast else buffer4,
                                buffer5[start:stop] if do_fujii else buffer5,
                                buffer6[start:stop] if do_im else buffer6, pairs, ratio_unit, n, weight)
                for r in range(run_ptr.shape[0]):
                    if spread:
                        for q in range(sample_ptr[r, i], sample_ptr[r, i + 1]):
                            v1, v2, v3, _, vc, vf, vi = pixel_values(exponential, do_abs, do_s2, do_s3, do_contrast,
                                                                     do_fujii, do_im, sample_index[q], abs_sum,
                                                                     ratio_sum, second, fourth, sq_sum, pairs,
                                                                     ratio_unit, n, weight)
                            _store(samples, q, v1, v2, v3, vc, vf, vi, True, True, True, True, True, True)
                    if want_s1:
                        _region_row(buffer1, 0, r, i, run_ptr, runs, shift, partials, block)
                    if do_s2:
                        _region_row(buffer2, 1, r, i, run_ptr, runs, shift, partials, block)
                    if do_s3:
                        _region_row(buffer3, 2, r, i, run_ptr, runs, shift, partials, block)
                    if do_contrast:
                        _region_row(buffer4, 3, r, i, run_ptr, runs, shift, partials, block)
                    if do_fujii:
                        _region_row(buffer5, 4, r, i, run_ptr, runs, shift, partials, block)
                    if do_im:
                        _region_row(buffer6, 5, r, i, run_ptr, runs, shift, partials, block)

    return block_sums, sample_values
