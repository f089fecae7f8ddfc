"""The time-resolved correlation at geometric ages (edgedsm.estimators.kinetics): slot ages, Eq. 1
against an independent computation, the noise and dark level out of the zero lag, τ at 1/e, the
statuses and the refusals."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edgedsm.errors import EstimatorError
from edgedsm.estimators.kinetics import (
    ABOVE,
    BELOW,
    OK,
    WARMING_UP,
    Kinetics,
    decorrelation_time,
    slot_schedule,
    white_step,
)
from edgedsm.estimators.noise import NoiseModel
from edgedsm.estimators.signal_quality import DARK, NOT_SPECKLE, SATURATED

EXACT = NoiseModel(gain=0.0, quantized=False)  # a noise-free camera: Eq. 1 as written


def speckle(rng: np.random.Generator, shape: tuple[int, int], mean: float = 100.0) -> np.ndarray:
    """Fully developed speckle: exponential intensities (contrast 1)."""
    return rng.exponential(mean, shape)


@pytest.mark.parametrize(("longest", "per_octave"), [(1, 4), (100, 1), (4096, 4), (10**6, 3), (50_000, 8)])
def test_the_schedule_is_a_cascade_with_ages_within_a_factor_of_their_nominal(longest: int, per_octave: int) -> None:
    lower, period = slot_schedule(longest, per_octave)
    q = 2.0 ** (1.0 / per_octave)
    assert lower[0] == 1 and period[0] == 1
    assert (lower[1:] == lower[:-1] + period[:-1]).all()  # slot k takes slot k-1's frame at its oldest
    assert (period[1:] % period[:-1] == 0).all()  # refreshes of slot k are refreshes of slot k-1
    assert ((lower + period - 1) / lower < q).all()
    assert lower[-1] <= longest < lower[-1] + period[-1]
    # evenly in log age: per octave between per_octave and 2·per_octave slots once periods exceed 1
    first = int(lower[period > 1][0]) if (period > 1).any() else longest
    for octave in range(int(math.log2(first)) + 1, int(math.log2(longest))):
        count = int(((lower >= 2**octave) & (lower < 2 ** (octave + 1))).sum())
        assert per_octave <= count <= 2 * per_octave, (octave, count)


def test_each_kept_frame_has_its_exact_age_and_its_own_pixels() -> None:
    rng = np.random.default_rng(3)
    shape = (12, 10)
    kinetics = Kinetics(np.ones(shape, bool), EXACT, longest_age=40, per_octave=2, flatten=0)
    lower, period = slot_schedule(40, 2)
    frames = []
    for n in range(200):
        frame = speckle(rng, shape)
        frames.append(frame)
        kinetics.push(frame)
        ages = kinetics.ages()
        filled = len(ages)
        # every filled slot: refreshed at the last multiple of its period with age L_k
        assert (ages == lower[:filled] + n % period[:filled]).all()
        if n >= 2 * lower[-1] + period[-1]:
            assert filled == lower.size
        if n % 7 == 0 and filled:
            corr = kinetics.correlation()
            now = frames[-1]
            for age, c, g in zip(corr.ages, corr.c, corr.g, strict=True):
                past = frames[-1 - age]
                expected_c = (now * past).mean() / (now.mean() * past.mean()) - 1.0  # Eq. 1
                beta_now = (now * now).mean() / now.mean() ** 2 - 1.0
                beta_past = (past * past).mean() / past.mean() ** 2 - 1.0
                assert c == pytest.approx(expected_c, rel=1e-5, abs=1e-6)
                assert g == pytest.approx(expected_c / math.sqrt(beta_now * beta_past), rel=1e-5, abs=1e-6)
            assert corr.beta == pytest.approx((now * now).mean() / now.mean() ** 2 - 1.0, rel=1e-6)
    assert kinetics.memory_bytes == (lower.size + 1) * shape[0] * shape[1] * 4


def test_a_masked_region_correlates_its_own_pixels_only() -> None:
    rng = np.random.default_rng(4)
    mask = np.zeros((20, 20), bool)
    mask[3:9, 5:17] = True
    mask[10:14, 2:4] = True  # not a rectangle: the pixels are gathered
    kinetics = Kinetics(mask, EXACT, longest_age=4, flatten=0)
    first, second = speckle(rng, mask.shape), speckle(rng, mask.shape)
    second[~mask] = 1e6  # what lies outside the region never counts
    kinetics.push(first)
    kinetics.push(second)
    a, b = second[mask], first[mask]
    assert kinetics.correlation().c[0] == pytest.approx((a * b).mean() / (a.mean() * b.mean()) - 1.0, rel=1e-5)


def test_the_dark_level_is_taken_out_before_eq_1() -> None:
    rng = np.random.default_rng(5)
    shape = (32, 32)
    offset = NoiseModel(gain=0.0, dark_mean=40.0, quantized=False)
    plain, shifted = (Kinetics(np.ones(shape, bool), model, 8, flatten=0) for model in (EXACT, offset))
    base = speckle(rng, shape)
    for _ in range(3):
        frame = 0.5 * base + speckle(rng, shape, 50.0)  # partly correlated frames
        plain.push(frame)
        shifted.push(frame + 40.0)
    np.testing.assert_allclose(shifted.correlation().c, plain.correlation().c, rtol=1e-5)
    assert shifted.correlation().beta == pytest.approx(plain.correlation().beta, rel=1e-6)


@pytest.mark.parametrize("flatten", [0, 9])
def test_shot_and_read_noise_leave_the_zero_lag(flatten: int) -> None:
    """A static speckle pattern under strong noise: every age sees the pattern only, so the
    normalised correlation is 1 once the noise is out of c(t, 0) (it would be 0.83 without)."""
    rng = np.random.default_rng(6)
    shape = (96, 96)
    model = NoiseModel(gain=20.0, dark_mean=200.0, dark_variance=30.0, quantized=False)
    pattern = speckle(rng, shape)
    lit = model.dark_mean + pattern  # above a dark level: the noise never reaches below 0
    kinetics = Kinetics(np.ones(shape, bool), model, 16, flatten=flatten)
    for _ in range(20):
        kinetics.push(lit + rng.normal(0.0, 1.0, shape) * np.sqrt(model.variance(lit)))
    corr = kinetics.correlation()
    raw = corr.c / (corr.beta + float(model.variance(lit).mean()) / pattern.mean() ** 2)
    assert raw.mean() < 0.9  # what the noise does to an uncorrected zero lag
    assert np.abs(corr.g - 1.0).max() < 0.03


def test_tau_of_an_exponential_correlation() -> None:
    """Per pixel an AR(1) complex Gaussian field, |g1(1)| = a: the intensity correlates as a^(2τ)
    (Siegert), so τ at 1/e is 1/(2 ln(1/a)) = 20 frames."""
    rng = np.random.default_rng(7)
    shape = (96, 96)
    a = math.exp(-1.0 / 40.0)
    field = (rng.normal(size=shape) + 1j * rng.normal(size=shape)) / math.sqrt(2.0)
    kinetics = Kinetics(np.ones(shape, bool), EXACT, 256, flatten=0)
    taus = []
    for n in range(220):
        kinetics.push(np.abs(field) ** 2)
        field = a * field + math.sqrt(1 - a * a) * (rng.normal(size=shape) + 1j * rng.normal(size=shape)) / math.sqrt(2)
        if n >= 100 and n % 2 == 0:
            result = kinetics.measure()
            assert result.status == OK
            assert result.rate == pytest.approx(1.0 / result.tau)
            taus.append(result.tau)
    assert np.median(taus) == pytest.approx(20.0, rel=0.03)
    assert np.std(taus) < 0.1 * 20.0  # frame by frame, no time average


def test_the_crossing_is_exact_for_stretched_exponentials() -> None:
    ages = slot_schedule(4096, 4)[0]
    for tau, power in ((3.3, 1.0), (71.0, 0.5), (900.0, 1.7)):
        status, found, bound = decorrelation_time(ages, np.exp(-((ages / tau) ** power)))
        assert status == OK and bound is None
        assert found == pytest.approx(tau, rel=1e-9)


def test_the_crossing_bounds_and_noisy_brackets() -> None:
    ages = np.array([1.0, 2.0, 4.0, 8.0])
    assert decorrelation_time(ages, np.array([0.9, 0.8, 0.7, 0.6])) == (ABOVE, None, 8.0)
    assert decorrelation_time(ages, np.array([0.3, 0.1, 0.0, 0.0])) == (BELOW, None, 1.0)
    assert decorrelation_time(ages, np.full(4, np.nan)) == (WARMING_UP, None, None)
    # NaN ages (a reference without contrast) are skipped
    assert decorrelation_time(ages, np.array([np.nan, 0.9, 0.8, 0.6]))[0] == ABOVE
    # noise pushed g above 1 or below 0 at a bracket end: linear in g against ln age
    status, tau, _ = decorrelation_time(ages, np.array([1.2, 1.1, -0.1, 0.0]))
    share = (1.1 - math.exp(-1.0)) / 1.2
    assert status == OK and tau == pytest.approx(math.exp(math.log(2.0) + share * math.log(2.0)))


def test_a_white_step_is_the_exponentials_intercept() -> None:
    ages = slot_schedule(1024, 3)[0]
    for amplitude, tau in ((0.835, 3.0), (0.5, 40.0), (1.0, 700.0)):
        assert white_step(ages, amplitude * np.exp(-ages / tau)) == pytest.approx(amplitude, rel=1e-12)
    assert white_step(np.array([2.0, 5.0]), np.array([0.8, 0.6])) == pytest.approx(
        math.exp((5 * math.log(0.8) - 2 * math.log(0.6)) / 3))  # actual ages, not 1 and 2
    assert white_step(ages[:3], np.array([0.9, 0.95, 0.9])) == pytest.approx(0.9)  # rising: at least g(a0)
    assert white_step(ages[:3], np.array([1.05, 1.02, 1.0])) == 1.0  # never above 1
    assert white_step(ages[:3], np.array([0.2, -0.01, 0.0])) == 1.0  # nothing left at the second age
    assert white_step(ages[:3], np.array([np.nan, 0.6, 0.36])) == pytest.approx(1.0)  # NaN skipped
    assert white_step(ages[:1], np.array([0.5])) == 1.0
    # a stretched decay is read as a step: exp(-(a/τ)^p) gives exp((2^p - 2)/τ^p) from ages 1, 2
    assert white_step(np.array([1.0, 2.0]), np.exp(-np.array([1.0, 2.0]) ** 0.5 / 10**0.5)) == pytest.approx(
        math.exp((2**0.5 - 2) / 10**0.5))


def test_white_phase_noise_is_taken_out_when_asked() -> None:
    """Per pixel an AR(1) field as above, each frame's scatterers seen through fresh phases of σ rad:
    the pixel's field keeps e^(-σ²/2) of itself and gains an independent Gaussian part (its
    correlation between frames falls by e^(-σ²), the intensity's by exp(-2σ²)); τ at 1/e reads short
    unless the step is taken out."""
    rng = np.random.default_rng(12)
    shape = (96, 96)
    a, sigma = math.exp(-1.0 / 60.0), 0.3  # τ = 30 frames
    field = (rng.normal(size=shape) + 1j * rng.normal(size=shape)) / math.sqrt(2.0)
    kinetics = Kinetics(np.ones(shape, bool), EXACT, 256, flatten=0)
    plain, white, amplitude = [], [], []
    for n in range(260):
        fresh = (rng.normal(size=shape) + 1j * rng.normal(size=shape)) / math.sqrt(2.0)
        kinetics.push(np.abs(math.exp(-sigma**2 / 2) * field + math.sqrt(1 - math.exp(-sigma**2)) * fresh) ** 2)
        field = a * field + math.sqrt(1 - a * a) * (rng.normal(size=shape) + 1j * rng.normal(size=shape)) / math.sqrt(2)
        if n >= 140 and n % 2 == 0:
            plain.append(kinetics.measure().tau)
            result = kinetics.measure(white=True)
            white.append(result.tau)
            amplitude.append(result.amplitude)
    assert kinetics.measure().amplitude == 1.0
    assert np.median(amplitude) == pytest.approx(math.exp(-2 * sigma**2), abs=0.03)
    assert np.median(white) == pytest.approx(30.0, rel=0.05)
    assert np.median(plain) == pytest.approx(30.0 * (1 - 2 * sigma**2), rel=0.05)  # exp(-2σ²)·exp(-τ/30) = 1/e


def test_identical_frames_are_above_independent_ones_below() -> None:
    rng = np.random.default_rng(8)
    shape = (64, 64)
    pattern = speckle(rng, shape)
    still = Kinetics(np.ones(shape, bool), EXACT, 100)
    fast = Kinetics(np.ones(shape, bool), EXACT, 100)
    for _ in range(150):
        still.push(pattern)
        fast.push(speckle(rng, shape))
    result = still.measure()
    assert (result.status, result.tau, result.rate) == (ABOVE, None, None)
    assert result.bound == still.ages()[-1] >= slot_schedule(100)[0][-1]
    np.testing.assert_allclose(result.correlation.g, 1.0, atol=1e-5)
    result = fast.measure()
    assert (result.status, result.bound) == (BELOW, 1.0)


def test_flat_dark_and_saturated_regions_read_as_such() -> None:
    shape = (24, 24)
    camera = NoiseModel(gain=0.25, dark_variance=1.0)
    for frame, status in ((np.full(shape, 120, np.uint8), NOT_SPECKLE),  # a constant region
                          (np.zeros(shape, np.uint8), DARK),
                          (np.full(shape, 255, np.uint8), SATURATED)):
        for flatten in (0, 9):
            kinetics = Kinetics(np.ones(shape, bool), camera, 32, flatten=flatten)
            for _ in range(5):
                kinetics.push(frame)
            result = kinetics.measure()
            assert (result.status, result.tau, result.rate, result.correlation) == (status, None, None, None)
    one = np.zeros(shape, bool)
    one[5, 7] = True  # a single constant pixel
    kinetics = Kinetics(one, camera, 32)
    for _ in range(3):
        kinetics.push(np.full(shape, 90, np.uint8))
    assert kinetics.measure().status == NOT_SPECKLE


def test_signed_and_wide_integer_frames_are_intensities_too() -> None:
    rng = np.random.default_rng(11)
    model = NoiseModel(gain=0.25, dark_variance=1.0)
    frames = [rng.integers(0, 4000, (24, 24)) for _ in range(4)]
    results = []
    for dtype in (np.uint16, np.int16, np.int32, np.uint32):
        kinetics = Kinetics(np.ones((24, 24), bool), model, 8, top=4095.0)
        for frame in frames:
            kinetics.push(frame.astype(dtype))
        results.append(kinetics.correlation())
    for other in results[1:]:
        np.testing.assert_allclose(other.c, results[0].c, rtol=1e-6)
        assert other.beta == pytest.approx(results[0].beta, rel=1e-9)


def test_the_first_frame_is_warming_up() -> None:
    kinetics = Kinetics(np.ones((16, 16), bool), EXACT, 8)
    kinetics.push(speckle(np.random.default_rng(9), (16, 16)))
    result = kinetics.measure()
    assert (result.status, result.tau, result.frame) == (WARMING_UP, None, 0)
    assert kinetics.ages().size == 0


def test_refusals() -> None:
    good = np.ones((8, 8), bool)
    for mask in (np.ones((8, 8)), np.zeros((8, 8), bool), np.ones((2, 8, 8), bool)):
        with pytest.raises(EstimatorError, match="mask"):
            Kinetics(mask, EXACT, 8)
    with pytest.raises(EstimatorError, match="NoiseModel"):
        Kinetics(good, 0.25, 8)
    for longest in (0, True, 8.0, -3):
        with pytest.raises(EstimatorError, match="longest_age"):
            Kinetics(good, EXACT, longest)
    for per in (0, 65, 2.5):
        with pytest.raises(EstimatorError, match="per_octave"):
            Kinetics(good, EXACT, 8, per_octave=per)
    for flatten in (1, 2, 4, -1, 300):
        with pytest.raises(EstimatorError, match="flatten"):
            Kinetics(good, EXACT, 8, flatten=flatten)
    for top in (0, -1.0, math.nan, math.inf, True):
        with pytest.raises(EstimatorError, match="top"):
            Kinetics(good, EXACT, 8, top=top)
    kinetics = Kinetics(good, EXACT, 8)
    for call in (kinetics.measure, kinetics.correlation):
        with pytest.raises(EstimatorError, match="no frame"):
            call()
    for frame in (np.ones((8, 9)), np.ones((8, 8), complex), np.full((8, 8), np.nan), np.full((8, 8), -1, np.int16)):
        with pytest.raises(EstimatorError, match="frame"):
            kinetics.push(frame)
    assert kinetics.frames_seen == 0  # a refused frame changes nothing
    with pytest.raises(EstimatorError, match="ages"):
        decorrelation_time(np.array([1.0, 1.0]), np.array([0.5, 0.2]))
    with pytest.raises(EstimatorError, match="ages"):
        decorrelation_time(np.array([1.0, 2.0]), np.array([0.5]))
    with pytest.raises(EstimatorError, match="ages"):
        white_step(np.array([0.0, 2.0]), np.array([0.5, 0.2]))


def test_the_fused_pass_is_the_numpy_path() -> None:
    pytest.importorskip("numba")
    rng = np.random.default_rng(10)
    model = NoiseModel(gain=0.25, dark_mean=3.0, dark_variance=2.0)
    mask = np.zeros((40, 50), bool)
    mask[2:30, 5:49] = True
    mask[35:40, 0:3] = True  # at the frame's corner: boxes cut by its edges
    for region in (mask, np.ones_like(mask)):
        numpy_path = Kinetics(region, model, 64, kernel="numpy")
        fused = Kinetics(region, model, 64, kernel="numba")
        for n in range(80):
            frame = rng.integers(0, 256, mask.shape, dtype=np.uint8)
            frame[:4, :6] = 255 if n % 2 else 0  # saturated and dark corners
            frame[10:20, 10:30] = 2  # a dim patch: pixels below the lit level
            numpy_path.push(frame)
            fused.push(frame)
        np.testing.assert_allclose(fused._pool, numpy_path._pool, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(fused._beta, numpy_path._beta, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(fused._mean, numpy_path._mean, rtol=1e-12)
        assert fused.measure().status == numpy_path.measure().status


def test_a_kernel_is_one_of_the_known() -> None:
    with pytest.raises(EstimatorError, match="kernel"):
        Kinetics(np.ones((8, 8), bool), EXACT, 8, kernel="fortran")
    with pytest.raises(EstimatorError, match="kernel 'numba'"):
        Kinetics(np.ones((8, 8), bool), EXACT, 8, flatten=0, kernel="numba")
