"""The field's descriptors in the streaming engine (issue 24): temporal contrast, Fujii, the
inertia moment and the generalized differences equal their batch references
(edgedsm.estimators.descriptors) in the window modes (contrast, IM and GD bit for bit, Fujii within
the S2 fixed-point bound), follow a direct weighted reference in the exponential mode (GD: none),
and are never NaN on dark, saturated or constant pixels."""

from __future__ import annotations

import importlib.util
from fractions import Fraction

import numpy as np
import pytest

from edgedsm.errors import EstimatorError
from edgedsm.estimators import SlidingWindow, descriptors
from edgedsm.estimators.fixed_point import s2_error_bound
from edgedsm.estimators.lag_products import TAU_BATCH
from edgedsm.estimators.region_box import RegionBox
from edgedsm.estimators.region_stats import RegionPlan, region_moments
from edgedsm.estimators.snapshot import maps_from

KERNELS = ["numpy"] + (["numba"] if importlib.util.find_spec("numba") else [])
NEW = ("contrast", "fujii", "im")
SHAPE = (6, 10)


def stream(kind: str, bits: int, frames: int, seed: int = 0) -> np.ndarray:
    """(frames, 6, 10) of ``bits``-bit data: random, or adversarial (rows: dark, saturated, a
    constant level, 0/top alternating, a single flash, random)."""
    rng = np.random.default_rng(seed + bits)
    top = (1 << bits) - 1
    data = rng.integers(0, top + 1, (frames, *SHAPE), dtype=np.int64)
    if kind == "adversarial":
        data[:, 0] = 0
        data[:, 1] = top
        data[:, 2] = top // 3
        data[::2, 3] = top
        data[1::2, 3] = 0
        data[:, 4] = 0
        data[frames // 2, 4] = top
    return data.astype(np.uint8 if bits <= 8 else np.uint16)


def fujii_exact(window: np.ndarray, lag: int) -> np.ndarray:
    """200/(N-m)·Σ|a-b|/(a+b) in rational arithmetic (0 where a + b = 0), rounded once."""
    n = window.shape[0]
    flat = window.reshape(n, -1).astype(np.int64)
    out = np.empty(flat.shape[1])
    for p in range(flat.shape[1]):
        total = sum((Fraction(abs(int(a) - int(b)), int(a) + int(b)) for a, b in
                     zip(flat[:-lag, p], flat[lag:, p], strict=True) if a + b), Fraction(0))
        out[p] = float(200 * total / (n - lag))
    return out.reshape(window.shape[1:])


def check_window_maps(maps: dict[str, np.ndarray], window: np.ndarray, lag: int, bits: int) -> None:
    np.testing.assert_array_equal(maps["contrast"], descriptors.contrast(window))
    np.testing.assert_array_equal(maps["im"], descriptors.im(window, lag))
    pairs = window.shape[0] - lag
    # the engine's S2 bound, scaled by 200, and the rounding of that product (Fujii <= 200)
    bound = 200 * s2_error_bound(pairs, bits, 0.0) + 200 * 2.0**-53
    assert np.abs(maps["fujii"] - fujii_exact(window, lag)).max() <= bound
    # the batch reference has its own float64 summation error, about (N-m)·u of S2
    batch = 200 * (s2_error_bound(pairs, bits, 0.0) + (pairs + 2) * 2.0**-53)
    assert np.abs(maps["fujii"] - descriptors.fujii(window, lag)).max() <= batch
    for name in NEW:
        assert np.isfinite(maps[name]).all()


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("bits", [8, 12, 16])
@pytest.mark.parametrize("kind", ["random", "adversarial"])
def test_sliding_descriptors_equal_the_batch_references(kernel, bits, kind):
    n, m = 12, 3
    frames = stream(kind, bits, 70)
    engine = SlidingWindow(SHAPE, n, m, q=0, bits=bits, estimators=("s2", *NEW), kernel=kernel)
    for i, frame in enumerate(frames, 1):
        engine.push(frame)
        if i >= n and i % 7 == 0:  # many windows along the run: nothing drifts
            maps = engine.maps()
            check_window_maps(maps, frames[i - n:i], m, bits)
            np.testing.assert_array_equal(maps["fujii"], 200.0 * maps["s2"])


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("bits", [8, 16])
@pytest.mark.parametrize("kind", ["random", "adversarial"])
def test_tumbling_descriptors_equal_the_batch_references_of_the_last_block(kernel, bits, kind):
    n, m = 10, 2
    frames = stream(kind, bits, 47, seed=5)
    engine = SlidingWindow(SHAPE, n, m, q=0, bits=bits, estimators=NEW, mode="tumbling", kernel=kernel)
    for i, frame in enumerate(frames, 1):
        engine.push(frame)
        if i >= n:
            done = i // n * n
            check_window_maps(engine.maps(), frames[done - n:done], m, bits)


def exponential_reference(frames: np.ndarray, window: int, lag: int) -> dict[str, np.ndarray]:
    """The exponential mode's definitions evaluated directly: weights λ^k for the k-th newest
    frame (or pair (j-m, j)), λ = 1 - 1/N, normalised by their sum; σ² = Σw(I - ⟨I⟩)²/Σw."""
    x = frames.astype(np.float64)
    count = x.shape[0]
    decay = 1.0 - 1.0 / window
    w = decay ** np.arange(count - 1, -1, -1.0)
    mean = np.tensordot(w, x, 1) / w.sum()
    sigma = np.sqrt(np.tensordot(w, (x - mean) ** 2, 1) / w.sum())
    contrast = np.divide(sigma, mean, out=np.zeros_like(mean), where=mean > 0)
    a, b = x[:-lag], x[lag:]
    wp = decay ** np.arange(count - lag - 1, -1, -1.0)
    d = np.abs(b - a)
    ratio = np.divide(d, a + b, out=np.zeros_like(d), where=a + b > 0)
    return {"contrast": contrast, "fujii": 200 * np.tensordot(wp, ratio, 1) / wp.sum(),
            "im": np.tensordot(wp, d * d, 1) / wp.sum()}


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("bits", [8, 16])
@pytest.mark.parametrize("kind", ["random", "adversarial"])
def test_exponential_descriptors_follow_the_weighted_definitions(kernel, bits, kind):
    n, m = 15, 4
    frames = stream(kind, bits, 90, seed=9)
    engine = SlidingWindow(SHAPE, n, m, q=0, bits=bits, estimators=NEW, mode="exponential", kernel=kernel)
    for i, frame in enumerate(frames, 1):
        engine.push(frame)
        if i >= n and i % 11 == 0:
            maps, expected = engine.maps(), exponential_reference(frames[:i], n, m)
            for name in NEW:
                assert np.isfinite(maps[name]).all()
                # the running update rounds differently from the direct sums: relative 1e-9,
                # against values of order 1 (contrast), 100 (Fujii), up to 2^32 grey levels² (IM)
                np.testing.assert_allclose(maps[name], expected[name], rtol=1e-9, atol=1e-9, err_msg=name)
            if kind == "adversarial":  # dark, saturated and constant rows: exactly 0
                assert (maps["contrast"][:3] == 0).all() and (maps["fujii"][:3] == 0).all()
                assert (maps["im"][:3] == 0).all()


@pytest.mark.parametrize("mode", ["sliding", "tumbling", "exponential"])
def test_degenerate_pixels_are_zero_never_nan(mode):
    for bits in (8, 16):
        frames = stream("adversarial", bits, 40, seed=1)
        engine = SlidingWindow(SHAPE, 8, 1, q=0, bits=bits, estimators=NEW, mode=mode)
        for frame in frames:
            engine.push(frame)
        maps = engine.maps()
        for name in NEW:
            assert np.isfinite(maps[name]).all()
            assert (maps[name][0] == 0).all(), (name, "dark")  # ⟨I⟩ = 0: contrast defined as 0
            assert (maps[name][1:3] == 0).all(), (name, "saturated or constant")
        top = (1 << bits) - 1
        if mode != "exponential":  # 0/top alternating at lag 1: every pair differs by top
            assert (maps["fujii"][3] == 200.0).all() and (maps["im"][3] == float(top) ** 2).all()
            assert (maps["contrast"][3] == 1.0).all()  # σ = top/2 = ⟨I⟩ over an even window


@pytest.mark.parametrize("mode", ["sliding", "tumbling", "exponential"])
def test_snapshots_and_region_statistics_carry_the_new_maps(mode):
    frames = stream("adversarial", 8, 30, seed=3)
    shape = SHAPE
    new = NEW if mode == "exponential" else (*NEW, "gd")  # GD needs a window
    engine = SlidingWindow(shape, 9, 2, q=0, bits=8, estimators=("s1", "s3", *new), mode=mode)
    for frame in frames:
        engine.push(frame)
    maps = engine.maps()
    copied = maps_from(engine.snapshot(new))
    assert set(copied) == set(new)
    for name in new:
        np.testing.assert_array_equal(copied[name], maps[name])
    mask = np.zeros(shape, bool)
    mask[1:5, 2:9] = True
    plan = {"r": RegionPlan.of(RegionBox.of(mask), shape)}
    stats = region_moments(engine.snapshot(live=True), plan, new)["r"]
    assert set(stats) == set(new)
    if mode != "exponential":  # GD alone, means only (what the states need between two stats)
        alone = region_moments(engine.snapshot(["gd"], live=True), plan, ["gd"], spread=False)["r"]
        assert set(alone) == {"gd"} and alone["gd"].mean == stats["gd"].mean and alone["gd"].std == 0.0
        assert stats["gd"].mean > 0
    for name in new:
        expected = RegionBox.of(mask).stats(maps[name])
        assert stats[name].mean == pytest.approx(expected.mean, rel=1e-12, abs=1e-12)
        assert stats[name].std == pytest.approx(expected.std, rel=1e-9, abs=1e-9)
        assert stats[name].stats().median == expected.median


def test_the_inertia_sum_is_kept_only_when_asked_for():
    plain = SlidingWindow(SHAPE, 10, 2, bits=16)
    assert "sq" not in plain.array_bytes()
    with_im = SlidingWindow(SHAPE, 10, 2, bits=16, estimators=("s1", "im"))
    # 8 pairs of 16-bit differences: up to 8·65535² > 2^31, an int64 per pixel
    assert with_im.array_bytes()["sq"] == 8 * SHAPE[0] * SHAPE[1]
    assert with_im.array_bytes()["abs"] == plain.array_bytes()["abs"]
    eight = SlidingWindow(SHAPE, 10, 2, bits=8, estimators=("im",))
    assert eight.array_bytes()["sq"] == 4 * SHAPE[0] * SHAPE[1]  # 8·255² fits int32


def test_resync_reproduces_the_inertia_sum():
    frames = stream("random", 16, 40, seed=2)
    engine = SlidingWindow(SHAPE, 11, 3, q=0, bits=16, estimators=NEW)
    for frame in frames:
        engine.push(frame)
    before = engine._snapshot()
    engine.resync()
    after = engine._snapshot()
    for name in ("sq", "total", "total_sq", "ratio"):
        np.testing.assert_array_equal(after[name], before[name])


def test_fujii_needs_q_zero():
    with pytest.raises(EstimatorError, match=r"fujii.*q=0"):
        SlidingWindow(SHAPE, 10, 2, q=1.0, estimators=("fujii",))
    SlidingWindow(SHAPE, 10, 2, q=1.0, estimators=("contrast", "im"))  # the others take any q


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("bits", [8, 12, 16])
@pytest.mark.parametrize("kind", ["random", "adversarial"])
def test_sliding_gd_equals_the_batch_reference_bit_for_bit(kernel, bits, kind):
    n = 11
    frames = stream(kind, bits, 60, seed=7)
    engine = SlidingWindow(SHAPE, n, 2, bits=bits, estimators=("s1", "gd"), kernel=kernel)
    for i, frame in enumerate(frames, 1):
        engine.push(frame)
        if i >= n:  # every window, filling and sliding: the int64 sum never drifts
            gd = engine.maps(["gd"])["gd"]
            np.testing.assert_array_equal(gd, descriptors.gd(frames[i - n:i]))
    assert np.isfinite(gd).all()
    if kind == "adversarial":
        top = (1 << bits) - 1
        assert (gd[:3] == 0).all()  # dark, saturated, constant
        assert (gd[3] == top * 6 * 5 / (n * (n - 1) / 2)).all()  # 0/top alternating: 6·5 pairs differ by top
    before = engine._snapshot()["gd"]
    engine.resync()  # rebuilt from the ring by the sorted-values identity: the same integers
    np.testing.assert_array_equal(engine._snapshot()["gd"], before)


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("bits", [8, 12, 16])
@pytest.mark.parametrize("kind", ["random", "adversarial"])
@pytest.mark.parametrize("tau", [False, True])
def test_tumbling_gd_equals_the_batch_reference_of_the_last_block_bit_for_bit(kernel, bits, kind, tau):
    # with τc the ring has K + TAU_BATCH + 1 = 21 rows, rounded up to 3 blocks of N = 9: block k
    # starts at row 9k mod 27
    n = 9
    assert 4 + TAU_BATCH + 1 == 21
    frames = stream(kind, bits, 61, seed=11)
    engine = SlidingWindow(SHAPE, n, 2, bits=bits, estimators=("s1", "gd", *(("tau_c",) if tau else ())),
                           mode="tumbling", kernel=kernel, max_lag=4 if tau else None)
    assert engine.array_bytes()["ring"] == (3 * n if tau else n) * SHAPE[0] * SHAPE[1] * (1 if bits <= 8 else 2)
    for i, frame in enumerate(frames, 1):
        engine.push(frame)
        if i >= n:  # every push: the last completed block's map, whatever the block in progress
            done = i // n * n
            gd = engine.maps(["gd"])["gd"]
            np.testing.assert_array_equal(gd, descriptors.gd(frames[done - n:done]))
            np.testing.assert_array_equal(maps_from(engine.snapshot(["gd"]))["gd"], gd)
    assert np.isfinite(gd).all()
    if kind == "adversarial":  # the last block, frames 45..53: the flash at 30 is in no block of it
        top = (1 << bits) - 1
        assert (gd[:3] == 0).all() and (gd[4] == 0).all()  # dark, saturated, constant, unlit
        assert (gd[3] == top * 5 * 4 / (n * (n - 1) / 2)).all()  # 0/top alternating: 5·4 pairs differ by top


def test_gd_streams_in_the_window_modes_and_in_snapshots():
    with pytest.raises(EstimatorError, match="estimator 'gd': gd needs mode 'sliding' or 'tumbling', not 'expon"):
        SlidingWindow(SHAPE, 10, 2, estimators=("gd",), mode="exponential")
    engine = SlidingWindow(SHAPE, 4, 1, bits=8, estimators=("s2", "gd"))
    frames = stream("random", 8, 5)
    for frame in frames:
        engine.push(frame)
    copied = engine.snapshot()
    assert set(maps_from(copied)) == {"s2", "gd"} and copied.sums["gd"].dtype == np.int64
    np.testing.assert_array_equal(maps_from(copied)["gd"], descriptors.gd(frames[1:]))
    only = engine.snapshot(["gd"])  # GD alone: no maps kernel runs, the other sums are not copied
    assert set(maps_from(only)) == {"gd"} and only.nbytes == 8 * SHAPE[0] * SHAPE[1]
    assert "gd" not in maps_from(engine.snapshot(["s2"])) and engine.snapshot(["s2"]).sums["gd"].size == 0
    assert engine.array_bytes()["gd"] == 8 * SHAPE[0] * SHAPE[1]


@pytest.mark.slow
@pytest.mark.parametrize("bits", [8, 16])
def test_a_long_adversarial_run_leaves_no_drift(bits):
    """The last 200 000 frames of the long-run patterns (alternation, dark, saturated, flickers,
    constant, saw-tooth): the descriptors of the last window are still the batch references
    (int32 and int64 sums that add and remove for ever)."""
    from test_streaming_long import COUNT, adversarial_stream

    frames = adversarial_stream(COUNT, bits)[-200_000:]
    n, m = 200, 10
    engine = SlidingWindow((2, 4), n, m, q=0, bits=bits, estimators=(*NEW, "gd"))
    tumbling = SlidingWindow((2, 4), n, m, q=0, bits=bits, estimators=(*NEW, "gd"), mode="tumbling")
    for frame in frames:
        engine.push(frame)
        tumbling.push(frame)
    window = frames[-n:]
    check_window_maps(engine.maps(NEW), window, m, bits)
    check_window_maps(tumbling.maps(NEW), window, m, bits)  # 200 000 is a whole number of blocks
    np.testing.assert_array_equal(engine.maps(["gd"])["gd"], descriptors.gd(window))
    np.testing.assert_array_equal(tumbling.maps(["gd"])["gd"], descriptors.gd(window))
    assert engine.maps(["contrast"])["contrast"][1, 2] == 0.0  # constant pixel: σ = 0


def test_the_region_statistics_without_numba_give_the_same_descriptors():
    from edgedsm.estimators.region_stats import _moments_from_maps

    engine = SlidingWindow(SHAPE, 8, 2, q=0, bits=8, estimators=("s1", *NEW), kernel="numpy")
    for frame in stream("adversarial", 8, 12, seed=4):
        engine.push(frame)
    mask = np.zeros(SHAPE, bool)
    mask[:, 3:] = True
    plans = {"r": RegionPlan.of(RegionBox.of(mask), SHAPE)}
    fallback = _moments_from_maps(engine.snapshot(), plans, NEW, True)["r"]
    fused = region_moments(engine.snapshot(live=True), plans, NEW)["r"]
    for name in NEW:
        assert fallback[name].mean == pytest.approx(fused[name].mean, rel=1e-12, abs=1e-12)
        assert fallback[name].stats().median == fused[name].stats().median
