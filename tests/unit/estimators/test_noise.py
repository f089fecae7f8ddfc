"""Noise model, noise floors, above-noise activity and signal quality (docs/noise.md)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.special import ndtr

from edgedsm.errors import EstimatorError
from edgedsm.estimators import batch, descriptors, noise
from edgedsm.estimators import noise_floor as nf
from edgedsm.estimators import signal_quality as sq
from edgedsm.estimators.correlation_time import tau_c_bounds
from edgedsm.sim.scene import scene_from_dict
from edgedsm.sim.simulator import Simulator


def _camera(rng, electrons, gain, dark_sd, frames, shape, bits=8, offset=0.0):
    """Static target: Poisson electrons (mean map ``electrons``) times K, Gaussian dark noise
    around a dark ``offset`` (DN), rounded."""
    signal = offset + rng.poisson(electrons, (frames, *shape)) * gain + rng.normal(0.0, dark_sd, (frames, *shape))
    return np.clip(np.rint(signal), 0, 2**bits - 1).astype(np.uint8 if bits <= 8 else np.uint16)


def test_three_sources_agree_on_a_camera_of_known_gain():
    rng = np.random.default_rng(5)
    gain, dark_sd = 0.05, 0.6
    electrons = rng.uniform(200, 3000, (48, 48))  # a static target, pixels spread over the range
    dark = _camera(rng, np.zeros((48, 48)), gain, dark_sd, 16, (48, 48), offset=10.0)
    bright = _camera(rng, electrons, gain, dark_sd, 64, (48, 48), offset=10.0)
    sheet = noise.from_datasheet(gain, dark_sd / gain, dark_mean=10.0)
    ptc = noise.photon_transfer(dark, bright)
    own = noise.from_frames(bright)
    mu = np.array([30.0, 70.0, 150.0])
    truth = gain * (mu - 10.0) + dark_sd**2 + 1 / 12
    for model in (sheet, ptc, own):
        assert np.allclose(model.variance(mu), truth, rtol=0.06), (model, model.variance(mu), truth)
    assert ptc.gain == pytest.approx(gain, rel=0.05)
    assert own.gain == pytest.approx(gain, rel=0.1)


def test_noise_model_refuses_bad_parameters():
    with pytest.raises(EstimatorError):
        noise.NoiseModel(gain=-1.0)
    with pytest.raises(EstimatorError):
        noise.NoiseModel(gain=1.0, relative_error=1.5)
    with pytest.raises(EstimatorError):
        noise.photon_transfer(np.zeros((1, 8, 8), np.uint8), np.zeros((4, 8, 8), np.uint8))


def test_gaussian_floor_is_two_sigma_over_root_pi():
    model = noise.NoiseModel(gain=0.0, dark_variance=4.0, quantized=False)
    assert nf.mean_abs_difference(model, np.array([50.0]))[0] == pytest.approx(4.0 / math.sqrt(math.pi))
    # rounding: exact at σ = 0 (no difference ever) and Sheppard-like at large σ
    rounded = noise.NoiseModel(gain=0.0, dark_variance=0.0)
    assert nf.mean_abs_difference(rounded, np.array([50.3]))[0] == pytest.approx(0.0, abs=1e-9)
    wide = noise.NoiseModel(gain=0.0, dark_variance=9.0)
    assert nf.mean_abs_difference(wide, np.array([100.0]))[0] == pytest.approx(
        2 * 3 / math.sqrt(math.pi), rel=0.002)  # integer differences: no Sheppard term in E|Δ|


@settings(max_examples=25, deadline=None, derandomize=True)
# level in electrons: Gaussian enough from 50 on (docs/noise.md); σ from 0.07 to 39 DN
@given(level=st.floats(50.0, 3000.0), gain=st.floats(0.01, 0.5), dark_sd=st.floats(0.0, 2.0),
       bits=st.sampled_from([8, 10, 12]), lag=st.integers(1, 8), seed=st.integers(0, 2**16))
def test_pure_noise_reads_within_its_spread_of_zero(level, gain, dark_sd, bits, lag, seed):
    rng = np.random.default_rng(seed)
    shape, n = (24, 24), 40
    electrons = np.full(shape, level) * rng.uniform(0.5, 1.5, shape)
    top = 2**bits - 1
    assume(gain * level * 1.5 + 6 * math.sqrt(gain * gain * level * 1.5 + dark_sd**2) < top)  # no saturation
    frames = _camera(rng, electrons, gain, dark_sd, n, shape, bits)
    model = noise.from_datasheet(gain, dark_sd / gain)
    means = frames.mean(axis=0)
    maps = batch.all_maps(frames, lag)
    s1, s2, s3 = (float(maps[k].mean()) for k in ("s1", "s2", "s3"))
    share = nf.signal_share(model, means, float((batch.temporal_sigma(frames) ** 2).mean()), n, top=top)
    s1_floor = nf.s1_floor(model, means, n, lag, top=top)
    contrast = float(descriptors.contrast(frames).mean())
    contrast_floor, static = nf.contrast_floor_and_static_variance(model, means, n, top=top)
    assert static == pytest.approx(nf.static_variance(model, means, top=top), rel=1e-12)
    field_floors = ((descriptors.fujii(frames, lag), nf.fujii_floor(model, means, n, lag, top=top)),
                    (descriptors.im(frames, lag), nf.im_floor(model, means, n, lag, top=top)),
                    (descriptors.gd(frames), nf.gd_floor(model, means, n, top=top)),
                    (descriptors.contrast(frames), contrast_floor))
    for above in (nf.above_noise(s1, s1_floor), nf.above_noise(s2, nf.s2_floor(model, means, n, lag, top=top)),
                  share, nf.s3_signal(s3, s1, s1_floor, share), nf.contrast_signal(contrast, contrast_floor, share),
                  *(nf.above_noise(float(values.mean()), floor) for values, floor in field_floors)):
        assert abs(above.value) <= nf.LOW_SPREADS * above.spread, above
        assert above.verdict == nf.LOW, above


def test_constant_frames_have_no_signal():
    frames = np.full((20, 8, 8), 77, np.uint8)
    model = noise.NoiseModel(gain=0.1)
    means = frames.mean(axis=0)
    share = nf.signal_share(model, means, float((batch.temporal_sigma(frames) ** 2).mean()), 20)
    assert share.verdict == nf.NO_SIGNAL
    tau = tau_c_bounds(frames, 5, np.ones((8, 8), bool))
    assert nf.tau_verdict(tau.status, share) == nf.NO_SIGNAL
    s1_floor = nf.s1_floor(model, means, 20, 1)
    assert nf.s3_signal(0.0, 0.0, s1_floor, share).verdict == nf.NO_SIGNAL


# ----------------------------------------------------------------- the darkening film
N_MAX = 16000  # 0.016 DN per photon, as the glue recording's camera
STAGES = ((2.0, 1.0), (20.0, 0.6), (200.0, 0.3), (1e7, 0.1))  # (τc frames, light level): wet -> dry


@pytest.fixture(scope="module")
def drying_stages():
    """Four stages of a film whose light falls 10x while τc rises, 8-bit with shot noise."""
    stages = []
    for tau, level in STAGES:
        scene = scene_from_dict({"scene": {"size": 64, "frames": 64, "seed": 3}, "activity": {"tau_c": tau},
                                 "detector": {"n_max": N_MAX, "bits": 8},
                                 "exposure_steps": [{"frame": 0, "factor": level}]})
        stages.append(np.stack(list(Simulator(scene).frames())))
    return stages


def _stage_values(frames, model, lag):
    n, means = frames.shape[0], frames.mean(axis=0)
    maps = batch.all_maps(frames, lag)
    s1, s2, s3 = (float(maps[k].mean()) for k in ("s1", "s2", "s3"))
    share = nf.signal_share(model, means, float((batch.temporal_sigma(frames) ** 2).mean()), n, top=255)
    s1_floor = nf.s1_floor(model, means, n, lag, top=255)
    contrast = float(descriptors.contrast(frames).mean())
    return {"raw": (s1, s2, s3, contrast),
            "above": (nf.above_noise(s1, s1_floor), nf.above_noise(s2, nf.s2_floor(model, means, n, lag, top=255)),
                      nf.s3_signal(s3, s1, s1_floor, share),
                      nf.contrast_signal(contrast, nf.contrast_floor(model, means, n, top=255), share)),
            "share": share}


def test_darkening_film_reverses_s2_s3_and_the_noise_floor_removes_it(drying_stages):
    gain = 255 / (N_MAX + math.sqrt(N_MAX))  # the simulator's DN per photon
    model = noise.NoiseModel(gain=gain, relative_error=0.05)
    means = [float(frames.mean()) for frames in drying_stages]
    assert means[0] / means[-1] == pytest.approx(10.0, rel=0.15)
    lag = 5
    values = [_stage_values(frames, model, lag) for frames in drying_stages]
    raw_s3 = [v["raw"][2] for v in values]
    assert raw_s3[3] > 0.5 * raw_s3[0], raw_s3  # the dry film scores over half the wet one, as on glue
    for index in range(4):  # S1, S2, S3 and the contrast above noise: in order of drying
        above = [v["above"][index].value for v in values]
        assert above == sorted(above, reverse=True), (index, above)
        assert values[0]["above"][index].verdict == nf.OK
        assert values[3]["above"][index].verdict == nf.LOW, values[3]["above"][index]
        assert values[3]["above"][index].value < 0.05 * values[0]["above"][index].value
    shares = [v["share"].value for v in values]
    assert shares == sorted(shares, reverse=True) and values[3]["share"].verdict == nf.LOW
    # the camera's noise estimated from the slow stage's own frames gives the same verdicts
    own = noise.from_frames(drying_stages[2])
    assert own.gain == pytest.approx(gain, rel=0.15)
    own_values = [_stage_values(frames, own, lag) for frames in drying_stages]
    assert [v["above"][0].verdict for v in own_values] == [v["above"][0].verdict for v in values]


def test_from_frames_refuses_activity_faster_than_a_frame(drying_stages):
    with pytest.raises(EstimatorError, match="cannot tell noise from activity"):
        noise.from_frames(drying_stages[0])


# ----------------------------------------------------------------- signal quality
def _light(**kwargs):
    base = {"mean": 100.0, "dark_fraction": 0.0, "saturated_fraction": 0.0, "speckle_contrast": 0.6}
    return sq.LightStats(**{**base, **kwargs})


def test_signal_quality_cases():
    active = nf.AboveNoise(5.0, 0.1, 1.0, nf.OK)
    quiet = nf.AboveNoise(0.1, 0.1, 1.0, nf.LOW)
    assert sq.signal_quality(_light(), active).verdict == sq.OK
    assert sq.signal_quality(_light(), quiet).verdict == sq.LOW
    assert sq.signal_quality(_light(saturated_fraction=0.3), active) == sq.SignalQuality(sq.SATURATED, 0.0, 0.3)
    assert sq.signal_quality(_light(dark_fraction=0.8), active).verdict == sq.DARK
    assert sq.signal_quality(_light(speckle_contrast=0.05), active).verdict == sq.NOT_SPECKLE
    assert sq.signal_quality(_light(dark_fraction=0.5), active).verdict == sq.OK  # the bound itself passes
    with pytest.raises(EstimatorError):
        sq.signal_quality(_light(dark_fraction=1.5))


def test_light_stats_sees_saturation_darkness_and_blur(drying_stages):
    model = noise.NoiseModel(gain=255 / (N_MAX + math.sqrt(N_MAX)))
    wet = sq.light_stats(drying_stages[0], model, 255)
    assert wet.speckle_contrast > 0.5 and wet.dark_fraction < 0.2
    clipped = sq.light_stats(np.minimum(drying_stages[0], 20), model, 20)
    assert clipped.saturated_fraction > 0.5
    dark = sq.light_stats(drying_stages[0] // 40, model, 255)
    assert dark.dark_fraction > 0.5
    flat = np.repeat(drying_stages[0].mean(axis=(1, 2), keepdims=True), 64, 1).repeat(64, 2)
    blurred = sq.light_stats(np.rint(flat).astype(np.uint8), model, 255)
    assert blurred.speckle_contrast < sq.MIN_CONTRAST


def test_exact_rounding_meets_sheppard_where_the_sums_hand_over():
    model = noise.NoiseModel(gain=0.0, dark_variance=nf.EXACT_SIGMA**2 * 0.999)
    mu = np.array([500.3])
    exact = nf._rounded_moments(mu, np.sqrt(model.analog_variance(mu)), 0.0, math.inf)
    sheppard = nf._gaussian_moments(mu, model.analog_variance(mu), 0.0, quantized=True)
    assert exact[0][0] == pytest.approx(sheppard[0][0], rel=1e-3)
    assert exact[2][0] == pytest.approx(sheppard[2][0], rel=1e-3)


def _pair_moments_by_definition(nu, sigma, reach, q, top):
    """E|Δ|, E[Δ²], E[r], E[r²] of two rounded, clipped frames of analog mean ν, summed over every
    pair of the levels within ``reach`` of floor(ν) (the definition _rounded_moments sums in
    fewer steps)."""
    levels = np.floor(nu) + np.arange(-reach, reach + 1)
    prob = ndtr((levels + 0.5 - nu) / sigma) - ndtr((levels - 0.5 - nu) / sigma)
    value = np.clip(levels, 0.0, top)
    diff = np.abs(value[:, None] - value[None, :])
    total = value[:, None] + value[None, :] + q
    ratio = np.divide(diff, total, out=np.zeros_like(diff), where=total > 0)
    weight = prob[:, None] * prob[None, :]
    return [float((weight * term).sum()) for term in (diff, diff**2, ratio, ratio**2)]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(0.0, 300.0), st.floats(0.001, 3.99)), min_size=1, max_size=12),
       st.sampled_from([0.0, 0.5, 7.0]), st.sampled_from([255.0, 4095.0, math.inf]))
def test_rounded_moments_are_the_sums_over_pairs_of_levels(pixels, q, top):
    mu = np.array([min(m, top) for m, _ in pixels])
    sigma = np.array([s for _, s in pixels])
    got = nf._rounded_moments(mu, sigma, q, top)
    nu = nf._analog_means(mu, sigma, top)
    reach = math.ceil(6 * sigma.max()) + 2  # every pixel is summed over the widest σ's levels
    for index in range(mu.size):
        expected = _pair_moments_by_definition(nu[index], sigma[index], reach, q, top)
        for part, value in zip(got, expected, strict=True):
            assert part[index] == pytest.approx(value, rel=1e-12, abs=1e-20)  # far below any floor


#: DN: below, σ̂ of a pixel a few grey levels bright is too discrete for the chi distribution the
#: contrast's floor assumes (its floor then reads about a spread high; docs/noise.md)
CONTRAST_CALIBRATED_FROM = 5.0


def test_pure_noise_spread_is_calibrated():
    """With the camera's exact model (no model error), (estimate - floor)/spread over many pure
    noise windows has mean ~0 and standard deviation ~1: the floors are unbiased and the spreads
    are neither too wide nor too narrow."""
    rng = np.random.default_rng(11)
    z = {"s1": [], "s2": [], "share": [], "fujii": [], "im": [], "gd": [], "contrast": []}
    for _ in range(60):
        level, dark_sd = rng.uniform(50, 1500), rng.uniform(0, 2)
        gain = math.exp(rng.uniform(math.log(0.01), math.log(0.1)))
        lag = int(rng.integers(1, 9))
        frames = _camera(rng, np.full((24, 24), level) * rng.uniform(0.5, 1.5, (24, 24)), gain, dark_sd, 40, (24, 24))
        model = noise.from_datasheet(gain, dark_sd / gain, relative_error=0.0)
        means = frames.mean(axis=0)
        maps = batch.all_maps(frames, lag)
        for name, above in (
                ("s1", nf.above_noise(float(maps["s1"].mean()), nf.s1_floor(model, means, 40, lag, top=255))),
                ("s2", nf.above_noise(float(maps["s2"].mean()), nf.s2_floor(model, means, 40, lag, top=255))),
                ("share", nf.signal_share(model, means, float((batch.temporal_sigma(frames) ** 2).mean()), 40,
                                          top=255)),
                ("fujii", nf.above_noise(float(descriptors.fujii(frames, lag).mean()),
                                         nf.fujii_floor(model, means, 40, lag, top=255))),
                ("im", nf.above_noise(float(descriptors.im(frames, lag).mean()),
                                      nf.im_floor(model, means, 40, lag, top=255))),
                ("gd", nf.above_noise(float(descriptors.gd(frames).mean()), nf.gd_floor(model, means, 40, top=255))),
                ("contrast", nf.above_noise(float(descriptors.contrast(frames).mean()),
                                            nf.contrast_floor(model, means, 40, top=255)))):
            if name == "contrast" and frames.mean() < CONTRAST_CALIBRATED_FROM:
                continue
            z[name].append(above.value / above.spread)
    assert len(z["contrast"]) >= 40
    for name, values in z.items():
        assert abs(np.mean(values)) < 0.35 and 0.7 < np.std(values) < 1.3, (name, np.mean(values), np.std(values))


def test_independent_pixels_sees_interpolated_noise():
    rng = np.random.default_rng(2)
    white = rng.normal(100.0, 3.0, (30, 64, 65))
    assert noise.independent_pixels(white[:, :, :64]) == pytest.approx(64 * 64, rel=0.01)
    paired = (white[:, :, :-1] + white[:, :, 1:]) / 2.0  # neighbours share half their noise: ρ = 1/2
    expected = 64 * 64 / (1.0 + 2.0 * float(noise.abs_correlation(0.5)))
    assert noise.abs_correlation(0.5) == pytest.approx(0.224, abs=1e-3)
    assert noise.independent_pixels(paired) == pytest.approx(expected, rel=0.02)


@pytest.mark.parametrize("electrons, gain", [(3.0, 0.1), (3.0, 2.0), (30.0, 2.0)])
def test_low_counts_stay_within_the_stated_approximation(electrons, gain):
    """Poisson counts of a few electrons are not Gaussian: docs/noise.md states the floors' error
    there (S1 within 3 %, S2 within 8 % at 3 electrons and 2 DN per electron)."""
    rng = np.random.default_rng(1)
    frames = _camera(rng, np.full((32, 32), electrons) * rng.uniform(0.5, 1.5, (32, 32)), gain, 0.3, 40, (32, 32),
                     bits=10, offset=5.0)
    model = noise.from_datasheet(gain, 0.3 / gain, dark_mean=5.0, relative_error=0.0)
    means, maps = frames.mean(axis=0), batch.all_maps(frames, 2)
    s1_floor = nf.s1_floor(model, means, 40, 2, top=1023).value
    s2_floor = nf.s2_floor(model, means, 40, 2, top=1023).value
    assert float(maps["s1"].mean()) == pytest.approx(s1_floor, rel=0.03)
    assert float(maps["s2"].mean()) == pytest.approx(s2_floor, rel=0.08)


def test_speckle_decorrelating_within_a_frame_gives_no_model_rather_than_a_noise_as_large_as_itself():
    rng = np.random.default_rng(8)
    fast = np.clip(rng.exponential(80.0, (64, 48, 48)), 0, 255).astype(np.uint8)  # a new pattern every frame
    with pytest.raises(EstimatorError, match="cannot tell noise from activity"):
        noise.from_frames(fast, saturation=255)
    static = np.clip(np.rint(rng.poisson(np.broadcast_to(fast[0] / 0.5, fast.shape)) * 0.5), 0, 255).astype(np.uint8)
    assert noise.from_frames(static, saturation=255).gain == pytest.approx(0.5, rel=0.2)


def test_the_saturated_share_counts_clipped_samples_not_pixels_that_touch_full_scale_once():
    rng = np.random.default_rng(9)
    fast = np.clip(rng.exponential(40.0, (200, 32, 32)), 0, 255).astype(np.uint8)  # exp(-255/40): 0.17 % clipped
    light = sq.light_stats(fast, noise.NoiseModel(gain=0.5), 255)
    assert (fast.max(axis=0) == 255).mean() > 0.25  # a quarter of the pixels touch full scale in 200 frames
    assert light.saturated_fraction == pytest.approx((fast == 255).mean()) and light.saturated_fraction < 0.01
    assert sq.signal_quality(light).verdict != sq.SATURATED


def test_the_gd_spread_constant_is_the_conditional_variance_of_a_gaussian_mean_difference():
    z = np.linspace(-10.0, 10.0, 200_001)
    density = np.exp(-z * z / 2) / math.sqrt(2 * math.pi)
    conditional = 2 * density + z * (2 * ndtr(z) - 1)  # E|z - Z'|
    first = np.trapezoid(conditional * density, z)
    assert first == pytest.approx(2 / math.sqrt(math.pi), rel=1e-9)
    assert pytest.approx(np.trapezoid(conditional**2 * density, z) - first**2, rel=1e-7) == nf.GD_ZETA1


def scan_white_variance(structure: np.ndarray, lags: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """white_variance's definition, one grid point at a time: lstsq of [1, rise], the bounds, the
    first best residual."""
    k = lags.astype(np.float64)
    best, white_best, tau_best = np.full(len(structure), np.inf), np.zeros(len(structure)), np.zeros(len(structure))
    for p in noise._STRETCH:
        for tau in noise._TAU_GRID:
            rise = 1.0 - np.exp(-(k / tau) ** p)
            (white, slope), *_ = np.linalg.lstsq(np.stack([np.ones_like(k), rise], axis=1), structure.T, rcond=None)
            flat = slope < 0
            white, slope = np.where(flat, structure.mean(axis=1), white), np.where(flat, 0.0, slope)
            through = white < 0
            slope = np.where(through, structure @ rise / (rise @ rise), slope)
            white = np.where(through, 0.0, white)
            resid = ((structure - white[:, None] - slope[:, None] * rise) ** 2).sum(axis=1)
            better = resid < best
            best, white_best, tau_best = np.where(better, resid, best), np.where(better, white, white_best), \
                np.where(better, tau, tau_best)
    return white_best / 2.0, tau_best


def test_white_variance_is_the_grid_scan_of_least_squares_fits() -> None:
    """All grid points at once (pseudo-inverses) equal the scan of one lstsq per point: the same
    white noise, and the same τ where D(k) rises (where it is flat, fits at every τ tie to
    rounding and τ is arbitrary, as from_frames says)."""
    rng = np.random.default_rng(5)
    lags = np.arange(1, 7)
    white = rng.uniform(0.5, 20.0, 40)
    tau, p = np.exp(rng.uniform(np.log(1.5), np.log(300.0), 40)), rng.choice(noise._STRETCH, 40)
    rise = 1 - np.exp(-(lags / tau[:, None]) ** p[:, None])
    structure = (2 * white[:, None] + rng.uniform(20, 400, 40)[:, None] * rise) * (1 + rng.normal(0.0, 0.01, (40, 6)))
    structure[:5] = structure[:5, :1]  # flat
    got, expected = noise.white_variance(structure, lags), scan_white_variance(structure, lags)
    assert np.allclose(got[0], expected[0], rtol=1e-12, atol=0.0)
    assert np.array_equal(got[1][5:], expected[1][5:])
