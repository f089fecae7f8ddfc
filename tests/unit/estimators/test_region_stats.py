"""Region statistics straight from the engine's sums (issue 13): the fused pass gives the numbers
of float maps (``maps_from``) reduced by ``RegionBox.stats``, in every mode, on degenerate pixels,
on the live sums and on cropped engines (``estimator.area = "regions"``)."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from edgedsm.estimators import SlidingWindow
from edgedsm.estimators.region_box import PERCENTILE_SAMPLES, RegionBox, RegionStats, bounding_box
from edgedsm.estimators.region_stats import RegionPlan, _moments_from_maps, region_moments
from edgedsm.estimators.snapshot import maps_from
from tests.unit.estimators.test_streaming import MODES, feed

HAS_NUMBA = importlib.util.find_spec("numba") is not None
RTOL = 1e-12


def frames_with_degenerate_pixels(shape: tuple[int, int], count: int, bits: int, seed: int) -> np.ndarray:
    """Random frames in which some pixels never change: dark (0), saturated (top) and a constant
    mid level, so σ = 0 (S3 defined as 0) and |ΔI| = 0 occur inside the regions."""
    top = (1 << bits) - 1
    rng = np.random.default_rng(seed)
    frames = rng.integers(0, top + 1, size=(count, *shape), dtype=np.uint8 if bits <= 8 else np.uint16)
    frames[:, :3, :] = 0
    frames[:, 3:5, :] = top
    frames[:, 5:9, : shape[1] // 2] = top // 3
    frames[:, -4:, :] //= 7  # a darker, still varying band
    return frames


def masks_for(shape: tuple[int, int], seed: int) -> dict[str, np.ndarray]:
    height, width = shape
    rng = np.random.default_rng(seed)
    rect = np.zeros(shape, bool)
    rect[height // 5: 4 * height // 5, width // 3: width - 2] = True
    scattered = rng.random(shape) < 0.3
    constant = np.zeros(shape, bool)
    constant[:9, : width // 2] = True  # every pixel dark, saturated or constant: S3 = 0, S1 = S2 = 0
    single = np.zeros(shape, bool)
    single[height // 2, width // 2] = True
    return {"all": np.ones(shape, bool), "rect": rect, "scattered": scattered, "constant": constant,
            "single": single}


def assert_close(got: RegionStats, expected: RegionStats, label: str) -> None:
    assert got.pixels == expected.pixels, label
    scale = max(abs(expected.mean), abs(expected.std), 1e-300)
    for field in ("mean", "p05", "median", "p95"):
        a, b = getattr(got, field), getattr(expected, field)
        assert abs(a - b) <= RTOL * max(abs(b), 1e-300), (label, field, a, b)
    # the deviation relative to the map's scale: a constant region's is 0 (or roundoff of the mean)
    assert abs(got.std - expected.std) <= RTOL * scale, (label, "std", got.std, expected.std)


def reference(engine: SlidingWindow, masks: dict[str, np.ndarray]) -> dict[str, dict[str, RegionStats]]:
    maps = maps_from(engine.snapshot())
    return {name: {key: RegionBox.of(mask).stats(values) for key, values in maps.items()}
            for name, mask in masks.items()}


@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("bits", [8, 12, 16])  # 16: ΣI² in int64, the pass's integer N²σ² path
def test_fused_statistics_equal_maps_then_region_stats(mode: str, bits: int) -> None:
    shape = (96, 130)
    frames = frames_with_degenerate_pixels(shape, 37, bits, seed=bits)
    engine = feed(SlidingWindow(shape, window=20, lag=3, q=1.0, bits=bits, mode=mode), frames)
    masks = masks_for(shape, seed=5)
    expected = reference(engine, masks)
    plans = {name: RegionPlan.of(RegionBox.of(mask), shape) for name, mask in masks.items()}
    for parallel in (False, True):
        got = region_moments(engine.snapshot(live=True), plans, ("s1", "s2", "s3"), parallel=parallel)
        for name in masks:
            assert sorted(got[name]) == ["s1", "s2", "s3"]
            for key, stats in expected[name].items():
                assert_close(got[name][key].stats(), stats, f"{mode} {bits} {name} {key} parallel={parallel}")
    constant = region_moments(engine.snapshot(live=True), {"c": plans["constant"]}, ("s1", "s2", "s3"))["c"]
    assert all(m.mean == 0.0 and m.std == 0.0 for m in constant.values())  # nothing moved there


@pytest.mark.parametrize("mode", MODES)
def test_the_numpy_path_gives_the_same_numbers(mode: str) -> None:
    shape = (40, 50)
    frames = frames_with_degenerate_pixels(shape, 25, 8, seed=3)
    engine = feed(SlidingWindow(shape, window=12, lag=2, q=1.0, bits=8, mode=mode), frames)
    masks = masks_for(shape, seed=9)
    plans = {name: RegionPlan.of(RegionBox.of(mask), shape) for name, mask in masks.items()}
    expected = reference(engine, masks)
    got = _moments_from_maps(engine.snapshot(), plans, ("s1", "s2", "s3"), spread=True)
    for name in masks:
        for key, stats in expected[name].items():
            assert_close(got[name][key].stats(), stats, f"{mode} {name} {key}")


def test_parallel_and_serial_passes_agree_exactly() -> None:
    """Blocks of rows are fixed by the box, not by the threads: the same sums in the same order."""
    shape = (300, 260)  # several blocks of BLOCK_PIXELS
    engine = feed(SlidingWindow(shape, window=10, lag=2, q=1.0, bits=8),
                  frames_with_degenerate_pixels(shape, 14, 8, seed=11))
    plans = {name: RegionPlan.of(RegionBox.of(mask), shape) for name, mask in masks_for(shape, seed=2).items()}
    serial = region_moments(engine.snapshot(live=True), plans, ("s1", "s2", "s3"), parallel=False)
    parallel = region_moments(engine.snapshot(live=True), plans, ("s1", "s2", "s3"), parallel=True)
    for name, per_map in serial.items():
        for key, moments in per_map.items():
            other = parallel[name][key]
            assert (moments.pixels, moments.mean, moments.std) == (other.pixels, other.mean, other.std)
            assert np.array_equal(moments.sample, other.sample)


def test_large_regions_take_the_same_percentile_sample() -> None:
    """Above PERCENTILE_SAMPLES pixels the percentiles come from every k-th pixel, as region_stats."""
    shape = (600, 500)
    assert shape[0] * shape[1] > PERCENTILE_SAMPLES
    engine = feed(SlidingWindow(shape, window=6, lag=1, q=1.0, bits=8),
                  frames_with_degenerate_pixels(shape, 8, 8, seed=4))
    mask = np.ones(shape, bool)
    mask[::7, ::3] = False
    plan = RegionPlan.of(RegionBox.of(mask), shape)
    assert plan.sample_index.size <= PERCENTILE_SAMPLES < plan.pixels
    got = region_moments(engine.snapshot(live=True), {"r": plan}, ("s2", "s3"))["r"]
    maps = maps_from(engine.snapshot())
    for key in ("s2", "s3"):
        assert np.array_equal(got[key].sample, maps[key][mask][:: -(-plan.pixels // PERCENTILE_SAMPLES)])
        assert_close(got[key].stats(), RegionBox.of(mask).stats(maps[key]), key)
    assert sorted(got) == ["s2", "s3"]


@pytest.mark.parametrize("mode", MODES)
def test_means_only_for_the_states(mode: str) -> None:
    shape = (50, 70)
    engine = feed(SlidingWindow(shape, window=15, lag=3, q=1.0, bits=8, mode=mode),
                  frames_with_degenerate_pixels(shape, 22, 8, seed=6))
    masks = masks_for(shape, seed=8)
    plans = {name: RegionPlan.of(RegionBox.of(mask), shape) for name, mask in masks.items()}
    got = region_moments(engine.snapshot(["s2"], live=True), plans, ["s2"], spread=False)
    s2 = engine.maps()["s2"]
    for name, mask in masks.items():
        moments = got[name]["s2"]
        assert list(got[name]) == ["s2"] and moments.std == 0.0 and moments.sample.size == 0
        expected = RegionBox.of(mask).mean(s2)
        assert abs(moments.mean - expected) <= RTOL * max(abs(expected), 1e-300), name


def test_regions_of_a_cropped_engine() -> None:
    """estimator.area = "regions": the engine sees the regions' bounding box only; the shifted
    boxes give the statistics of the full frame's maps."""
    shape = (120, 150)
    frames = frames_with_degenerate_pixels(shape, 30, 8, seed=7)
    masks = {name: mask for name, mask in masks_for(shape, seed=3).items() if name in ("rect", "single")}
    rows, cols = bounding_box(list(masks.values()))
    crop_shape = (rows.stop - rows.start, cols.stop - cols.start)
    assert crop_shape != shape
    full = feed(SlidingWindow(shape, window=18, lag=3, q=1.0, bits=8), frames)
    cropped = feed(SlidingWindow(crop_shape, window=18, lag=3, q=1.0, bits=8),
                   np.ascontiguousarray(frames[:, rows, cols]))
    plans = {name: RegionPlan.of(RegionBox.of(mask).shifted(rows, cols), crop_shape) for name, mask in masks.items()}
    got = region_moments(cropped.snapshot(live=True), plans, ("s1", "s2", "s3"))
    for name, per_map in reference(full, masks).items():
        for key, stats in per_map.items():
            assert_close(got[name][key].stats(), stats, f"{name} {key}")


def test_live_sums_follow_the_engine_and_a_snapshot_does_not() -> None:
    shape = (30, 40)
    frames = frames_with_degenerate_pixels(shape, 30, 8, seed=1)
    engine = feed(SlidingWindow(shape, window=10, lag=2, q=1.0, bits=8), frames[:20])
    plans = {"all": RegionPlan.of(RegionBox.of(np.ones(shape, bool)), shape)}
    copy, live = engine.snapshot(), engine.snapshot(live=True)
    before = region_moments(copy, plans, ["s1"])["all"]["s1"].mean
    feed(engine, frames[20:])
    assert region_moments(copy, plans, ["s1"])["all"]["s1"].mean == before
    after = region_moments(live, plans, ["s1"])["all"]["s1"].mean
    assert after != before
    assert after == pytest.approx(float(engine.maps()["s1"].mean()), rel=RTOL)


def test_unknown_maps_are_refused() -> None:
    engine = feed(SlidingWindow((8, 8), window=4, lag=1, bits=8),
                  np.random.default_rng(0).integers(0, 256, (5, 8, 8), dtype=np.uint8))
    with pytest.raises(ValueError, match="no region moments"):
        region_moments(engine.snapshot(live=True), {}, ["tau_c"])


@pytest.mark.skipif(not HAS_NUMBA, reason="the fused kernels need numba")
def test_the_fused_kernels_are_used_with_numba() -> None:
    from edgedsm.estimators.region_stats import _kernels

    assert _kernels(True, True, True, False, True) is not None
