"""The frequency bands in the streaming engine (edgedsm.estimators.dft_bins): band_low, band_high
and band_ratio equal the batch reference (edgedsm.estimators.bands) within the stated bound
N·ε·D² (times BOUND_FACTOR) in the sliding and tumbling modes, on random, adversarial and long
streams; constant pixels read 0, never NaN; the exponential mode and a split at Nyquist are
refused; only the smaller band's bins are kept (16 bytes per bin per pixel); snapshots and
region statistics carry them."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from edgedsm.errors import EstimatorError
from edgedsm.estimators import SlidingWindow, bands, descriptors
from edgedsm.estimators.dft_bins import BIN_BYTES, BOUND_FACTOR, BandPlan, error_bound
from edgedsm.estimators.region_box import RegionBox
from edgedsm.estimators.region_stats import RegionPlan, region_moments
from edgedsm.estimators.snapshot import maps_from
from tests.unit.estimators.test_streaming_descriptors import SHAPE
from tests.unit.estimators.test_streaming_descriptors import stream as descriptor_stream

KERNELS = ["numpy"] + (["numba"] if importlib.util.find_spec("numba") else [])
BANDS = ("band_low", "band_high", "band_ratio")
EPS = 2.0**-53


def stream(kind: str, bits: int, frames: int, seed: int = 0) -> np.ndarray:
    """(frames, 6, 10) of ``bits``-bit data: the descriptors' streams (random, or adversarial:
    dark, saturated, a constant level, 0/top alternating (all power at Nyquist), a single flash),
    the adversarial one with a full-scale slow tone in its last row (all power in the low band)."""
    data = descriptor_stream(kind, bits, frames, seed)
    if kind == "adversarial":
        top = (1 << bits) - 1
        t = np.arange(frames)[:, None]
        data[:, 5] = np.round(top / 2 * (1 + np.cos(2 * np.pi * t * np.linspace(0.01, 0.12, SHAPE[1]))))
    return data


def spread(frames: np.ndarray, i: int, n: int) -> np.ndarray:
    """D of each pixel: max - min of its intensities over the last 2N frames before ``i``."""
    recent = frames[max(0, i - 2 * n):i].astype(np.int64)
    return (recent.max(axis=0) - recent.min(axis=0)).astype(np.float64)


def check_bands(maps: dict[str, np.ndarray], window: np.ndarray, d: np.ndarray, q: float,
                dt: float | None = None, split: float | None = None) -> float:
    """The engine's bands against the batch reference: within the bound (plus σ²'s rounding for
    the derived band), the ratio within the bound carried through high/(low + q). Returns the
    largest error in units of N·ε·D²."""
    n = window.shape[0]
    low, high = bands.split_powers(window, dt, split)
    bound = error_bound(n, d) + 4 * EPS * (low + high)
    err = np.maximum(np.abs(maps["band_low"] - low), np.abs(maps["band_high"] - high))
    assert (err <= bound).all(), (err / bound).max()
    assert (maps["band_low"] >= 0).all() and (maps["band_high"] >= 0).all()
    reference = bands.ratio(low, high, q)
    denominator = low + q
    usable = denominator > 2 * bound  # the ratio is conditioned by its denominator
    allowed = np.divide(bound + reference * bound, denominator - bound, out=np.zeros_like(bound), where=usable)
    assert (np.abs(maps["band_ratio"] - reference)[usable] <= allowed[usable]).all()
    for name in BANDS:
        assert np.isfinite(maps[name]).all()
    return float((err / (n * EPS * np.maximum(d, 1) ** 2)).max())


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("bits", [8, 12, 16])
@pytest.mark.parametrize("kind", ["random", "adversarial"])
@pytest.mark.parametrize("mode", ["sliding", "tumbling"])
def test_bands_equal_the_batch_reference(kernel, bits, kind, mode):
    n, q = 12, 1.0
    frames = stream(kind, bits, 12 * n)  # 12 windows: every pixel re-anchored about 11 times
    engine = SlidingWindow(SHAPE, n, 1, q=q, bits=bits, estimators=("s3", *BANDS), mode=mode, kernel=kernel)
    worst = 0.0
    for i, frame in enumerate(frames, 1):
        engine.push(frame)
        if i >= n and (i % n == 0 or (mode == "sliding" and i % 5 == 0)):
            maps = engine.maps()
            window = frames[i - n:i]
            worst = max(worst, check_bands(maps, window, spread(frames, i, n), q))
            np.testing.assert_allclose(maps["band_low"] + maps["band_high"], engine.sigma() ** 2,
                                       rtol=1e-12, atol=1e-9)
    assert worst <= BOUND_FACTOR
    if kind == "adversarial":
        for row in (0, 1, 2):  # dark, saturated, constant: σ = 0, every band exactly 0
            for name in BANDS:
                assert (maps[name][row] == 0).all()
        top = (1 << bits) - 1
        # 0/top alternating: all of σ² = top²/4 at Nyquist, ratio (top²/4)/(0 + q)
        np.testing.assert_allclose(maps["band_high"][3], top * top / 4, rtol=1e-12)
        assert (maps["band_low"][3] <= error_bound(n, top)).all()


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("mode", ["sliding", "tumbling"])
def test_a_long_run_stays_within_the_bound(kernel, mode):
    """5 000 frames of 16-bit tones and noise at N = 32: the sliding DFT's rounding would grow
    with the pushes; the re-anchor keeps every window within the bound."""
    n, frames_count = 32, 5000
    rng = np.random.default_rng(11)
    t = np.arange(frames_count)[:, None, None]
    tone = 30000 * np.cos(2 * np.pi * t * rng.uniform(0, 0.5, SHAPE)) + rng.normal(0, 200, (frames_count, *SHAPE))
    frames = np.clip(np.round(32768 + tone), 0, 65535).astype(np.uint16)
    engine = SlidingWindow(SHAPE, n, 1, q=1.0, bits=16, estimators=BANDS, mode=mode, kernel=kernel,
                           dt=0.01, band_split=20.0)
    worst = 0.0
    for i, frame in enumerate(frames, 1):
        engine.push(frame)
        if i >= n and i % n == 0 and (i > frames_count - 10 * n or i % (7 * n) == 0):
            worst = max(worst, check_bands(engine.maps(), frames[i - n:i], spread(frames, i, n), 1.0,
                                           dt=0.01, split=20.0))
    assert worst <= BOUND_FACTOR


@pytest.mark.skipif("numba" not in KERNELS, reason="100 000 steps need the compiled kernel")
def test_without_the_reanchor_the_sliding_dft_drifts_past_the_bound():
    """The recursion alone (the kernel, no re-anchor) on 100 000 pushes of 16-bit noise: its
    rounding walks away (about as √pushes), past the bound the re-anchor keeps."""
    from edgedsm.estimators.kernels_numba import dft_kernel

    n, pixels, pushes = 16, 512, 100_000
    rng = np.random.default_rng(0)
    ks = np.arange(1, 5)
    step = dft_kernel(True, False)
    ring = rng.integers(0, 65536, (n, pixels)).astype(np.uint16)
    exact = np.fft.rfft(ring.astype(np.float64) - ring[0], axis=0)[ks]
    bins = np.stack([exact.real, exact.imag])
    for i in range(n, pushes):
        new = rng.integers(0, 65536, pixels).astype(np.uint16)
        step(new, ring[i % n], np.cos(2 * np.pi * ks / n), np.sin(2 * np.pi * ks / n), bins)
        ring[i % n] = new
    window = ring[[j % n for j in range(pushes - n, pushes)]].astype(np.float64)
    exact = np.fft.rfft(window - window[0], axis=0)[ks]
    drift = (2 * np.abs(bins[0] ** 2 + bins[1] ** 2 - np.abs(exact) ** 2) / n**2).max()
    assert drift > BOUND_FACTOR * n * EPS * 65535.0**2


PROPERTY = settings(max_examples=60, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@st.composite
def band_streams(draw):
    """(frames, window, bits, split): a random stream that fills its window at least once, its
    values often 0 or full scale, the split anywhere below Nyquist (cycles per frame)."""
    window = draw(st.integers(2, 20))
    bits = draw(st.sampled_from([1, 8, 12, 16]))
    length = draw(st.integers(window, 4 * window))
    top = 2**bits - 1
    elements = st.one_of(st.sampled_from([0, top]), st.integers(0, top))
    frames = draw(arrays(np.uint8 if bits <= 8 else np.uint16, (length, 2, 3), elements=elements))
    split = draw(st.floats(0.01, 0.49))
    assume(split < (window // 2) / window)  # a bin above the split (odd N: none at 0.5)
    return frames, window, bits, split


@PROPERTY
@given(band_streams(), st.sampled_from(KERNELS), st.sampled_from(["sliding", "tumbling"]))
def test_bands_property(stream_case, kernel, mode):
    frames, n, bits, split = stream_case
    engine = SlidingWindow(frames.shape[1:], n, 1, q=0.5, bits=bits, mode=mode, kernel=kernel,
                           estimators=BANDS, band_split=split)
    for frame in frames:
        engine.push(frame)
    end = len(frames) if mode == "sliding" else len(frames) // n * n
    check_bands(engine.maps(), frames[end - n:end], spread(frames, end, n), 0.5, split=split)


def test_only_the_smaller_band_is_kept_at_16_bytes_a_bin():
    pixels = SHAPE[0] * SHAPE[1]
    plan = BandPlan.of(64, 0.02, 5.0)  # 25 Hz Nyquist, resolution 0.78 Hz: 6 bins up to 5 Hz, 26 above
    assert plan.low.tolist() == [1, 2, 3, 4, 5, 6] and plan.high.size == 26 and plan.keeps_low
    engine = SlidingWindow(SHAPE, 64, 1, bits=8, estimators=("band_ratio",), dt=0.02, band_split=5.0)
    assert engine.array_bytes()["bins"] == BIN_BYTES * 6 * pixels
    high = SlidingWindow(SHAPE, 64, 1, bits=8, estimators=("band_ratio",), dt=0.02, band_split=20.0)
    assert high.array_bytes()["bins"] == BIN_BYTES * 7 * pixels  # (20, 25] Hz: 7 bins, against 25 below
    default = SlidingWindow(SHAPE, 64, 1, bits=8, estimators=("band_ratio",))  # split 0.25 cycles/frame
    assert default.array_bytes()["bins"] == BIN_BYTES * 16 * pixels
    plain = SlidingWindow(SHAPE, 64, 1, bits=8)
    both = SlidingWindow(SHAPE, 64, 1, bits=8, estimators=("s1", "s2", "s3", "band_ratio"))
    assert both.bytes_per_pixel - plain.bytes_per_pixel == BIN_BYTES * 16  # what the memory checks count
    tumbling = SlidingWindow(SHAPE, 64, 1, bits=8, estimators=("band_ratio",), mode="tumbling")
    assert tumbling.array_bytes()["bins"] == tumbling.array_bytes()["done_bins"] == BIN_BYTES * 16 * pixels
    assert tumbling.array_bytes()["band_origin"] == pixels


def test_bad_band_settings_are_refused():
    with pytest.raises(EstimatorError, match="finite window"):
        SlidingWindow(SHAPE, 16, 1, estimators=("band_ratio",), mode="exponential")
    with pytest.raises(EstimatorError, match="Nyquist frequency 25 Hz"):
        SlidingWindow(SHAPE, 16, 1, estimators=("band_ratio",), dt=0.02, band_split=25.0)
    with pytest.raises(EstimatorError, match=r"Nyquist frequency 0\.5 cycles per frame"):
        SlidingWindow(SHAPE, 16, 1, estimators=("band_low",), band_split=0.0)
    with pytest.raises(EstimatorError, match="dt"):
        SlidingWindow(SHAPE, 16, 1, estimators=("band_high",), dt=-1.0)
    with pytest.raises(EstimatorError, match=r"no frequency of a 9-frame window lies above.*0\.444444"):
        SlidingWindow(SHAPE, 9, 1, estimators=("band_high",), band_split=0.45)
    SlidingWindow(SHAPE, 16, 1, mode="exponential", band_split=99.0)  # no band asked: not read


@pytest.mark.parametrize("mode", ["sliding", "tumbling"])
def test_snapshots_and_region_statistics_carry_the_bands(mode):
    n = 8
    frames = stream("adversarial", 16, 32, seed=3)
    engine = SlidingWindow(SHAPE, n, 1, q=2.0, bits=16, estimators=("s1", "s2", "s3", "band_ratio"), mode=mode,
                           band_split=0.3)
    for frame in frames:
        engine.push(frame)
    direct = engine.maps()
    snapshot = engine.snapshot()
    assert snapshot.sums["bins"].shape == (2, 2, SHAPE[0] * SHAPE[1])  # j = 1, 2 below 0.3 (N = 8), as many as above
    for name, values in maps_from(snapshot).items():
        np.testing.assert_array_equal(values, direct[name])
    np.testing.assert_array_equal(maps_from(engine.snapshot(["band_ratio"]))["band_ratio"], direct["band_ratio"])
    left = np.zeros(SHAPE, bool)
    left[:, :4] = True
    left[0, 0] = False
    regions = {"left": RegionPlan.of(RegionBox.of(left), SHAPE), "right": RegionPlan.of(RegionBox.of(~left), SHAPE)}
    moments = region_moments(engine.snapshot(live=True), regions, ("s2", "band_ratio"))
    for name, mask in (("left", left), ("right", ~left)):
        values = direct["band_ratio"][mask]
        got = moments[name]["band_ratio"]
        assert got.pixels == mask.sum()
        assert got.mean == pytest.approx(values.mean(), rel=1e-12)
        assert got.std == pytest.approx(values.std(), rel=1e-9, abs=1e-12)
    only = region_moments(engine.snapshot(["band_ratio"], live=True), regions, ("band_ratio",))
    assert only["left"]["band_ratio"].mean == moments["left"]["band_ratio"].mean
    copies = engine.snapshot_buffers()
    assert copies.sums["bins"].nbytes == BIN_BYTES * 2 * SHAPE[0] * SHAPE[1]  # the daemon's memory check counts it


def test_resync_reanchors_every_pixel():
    n = 8
    frames = stream("random", 16, 30, seed=3)
    engine = SlidingWindow(SHAPE, n, 1, bits=16, estimators=("s1", "band_ratio"))
    for frame in frames:
        engine.push(frame)
    before = engine.maps(["band_ratio"])["band_ratio"]
    engine.resync()  # every pixel re-anchored from the ring
    np.testing.assert_allclose(engine.maps(["band_ratio"])["band_ratio"], before, rtol=1e-9)
    reference = bands.ratio(*bands.split_powers(frames[-n:]))
    np.testing.assert_allclose(engine.maps(["band_ratio"])["band_ratio"], reference, rtol=1e-9)


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("mode", ["sliding", "tumbling"])
@pytest.mark.parametrize("kind", ["random", "adversarial"])
def test_custom_bands_equal_band_power(kernel, mode, kind):
    """bands=[(lo, hi), ...] in Hz: one (K, H, W) map, each band within the bound of
    bands.band_power; the bins of the split's smaller band and of the bands are kept once."""
    n, dt, bits = 20, 0.01, 16  # 50 Hz Nyquist, 5 Hz resolution
    chosen = [(0.0, 12.0), (12.0, 30.0), (27.0, float("inf"))]  # bins 1-2, 3-6, 6-10 (overlapping)
    frames = stream(kind, bits, 8 * n, seed=5)
    engine = SlidingWindow(SHAPE, n, 1, bits=bits, estimators=("bands", *BANDS), mode=mode, kernel=kernel,
                           dt=dt, band_split=12.0, bands=chosen)
    assert engine._bins.plan.kept.tolist() == list(range(1, 11))  # split: 1-2 (low) kept; bands: 1-10
    for i, frame in enumerate(frames, 1):
        engine.push(frame)
        if i >= n and i % n == 0:
            maps = engine.maps()
            window = frames[i - n:i]
            assert maps["bands"].shape == (3, *SHAPE)
            reference = bands.band_power(window, chosen, dt)
            bound = error_bound(n, spread(frames, i, n))
            assert (np.abs(maps["bands"] - reference) <= bound).all()
            check_bands(maps, window, spread(frames, i, n), 0.0, dt, 12.0)
    if kind == "adversarial":
        assert (maps["bands"][:, 0:3] == 0).all()  # dark, saturated, constant: every band exactly 0
    assert np.isfinite(maps["bands"]).all()


def test_custom_bands_need_their_list_and_stay_out_of_snapshots():
    with pytest.raises(EstimatorError, match=r"estimator 'bands' needs the bands"):
        SlidingWindow(SHAPE, 16, 1, estimators=("bands",))
    with pytest.raises(EstimatorError, match=r"starts at or above the Nyquist frequency 50"):
        SlidingWindow(SHAPE, 20, 1, estimators=("bands",), dt=0.01, bands=[(60.0, 70.0)])
    with pytest.raises(EstimatorError, match="finite window"):
        SlidingWindow(SHAPE, 16, 1, estimators=("bands",), bands=[(0.1, 0.2)], mode="exponential")
    engine = SlidingWindow(SHAPE, 16, 1, bits=8, estimators=("s1", "bands"), bands=[(0.1, 0.2)])
    assert engine.array_bytes()["bins"] == BIN_BYTES * 2 * SHAPE[0] * SHAPE[1]  # f = 2/16, 3/16
    for frame in stream("random", 8, 16):
        engine.push(frame)
    with pytest.raises(EstimatorError, match="does not carry 'bands'"):
        engine.snapshot(["bands"])
    assert engine.snapshot().estimators == ("s1",)


@pytest.mark.parametrize("mode", ["sliding", "tumbling"])
def test_bands_beside_gd_and_tau(mode):
    """The bands beside the other accumulators that read the ring (GD, τc): each still equals
    its batch reference (the tumbling ring then holds whole blocks, the bins their own origin)."""
    n = 10
    frames = stream("adversarial", 12, 6 * n, seed=2)
    engine = SlidingWindow(SHAPE, n, 2, q=1.0, bits=12, estimators=("s3", "gd", "tau_c", *BANDS), mode=mode,
                           max_lag=4)
    for i, frame in enumerate(frames, 1):
        engine.push(frame)
        if i >= n and i % n == 0:
            maps = engine.maps()
            window = frames[i - n:i]
            check_bands(maps, window, spread(frames, i, n), 1.0)
            np.testing.assert_array_equal(maps["gd"], descriptors.gd(window))
