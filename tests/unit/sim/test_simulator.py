"""Physics of the §2A simulator: statistics that fully developed dynamic speckle must have."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import j1

from edgedsm.sim import Simulator, scene_from_dict, simulate


def make(size=64, tau_c=10.0, frames=50, seed=1, **tables):
    data = {"scene": {"size": size, "frames": frames, "seed": seed, "speckle_size": tables.pop("speckle", 2.0)},
            "activity": {"tau_c": tau_c}}
    data.update(tables)
    return scene_from_dict(data)


def test_static_speckle_is_fully_developed_before_detection():
    grid = Simulator(make(size=128)).next_grid_intensity().astype(np.float64)
    mean = grid.mean()
    assert grid.std() / mean == pytest.approx(1.0, abs=0.03)  # contrast of fully developed speckle
    assert mean == pytest.approx(1.0, abs=0.05)  # uniform light, pupil normalised
    # exponential intensity PDF: P(I > t<I>) = exp(-t)
    for t in (0.5, 1.0, 2.0, 3.0):
        assert (grid > t * mean).mean() == pytest.approx(np.exp(-t), rel=0.08)
    assert (grid**2).mean() / mean**2 == pytest.approx(2.0, rel=0.06)


def test_pixel_integration_lowers_contrast():
    sim = Simulator(make(size=128))
    intensity = sim.next_intensity()
    contrast = intensity.std() / intensity.mean()
    assert 0.6 < contrast < 0.97  # 2x2 averaging over ~2-px speckles


def test_intensity_correlation_follows_exp_minus_tau_over_tau_c():
    tau_c = 10.0
    sim = Simulator(make(size=64, tau_c=tau_c))
    frames = np.stack([sim.next_intensity() for _ in range(300)]).astype(np.float64)
    mu, var = frames.mean(), frames.var()
    for lag in (2, 5, 10, 20):
        cov = ((frames[:-lag] - mu) * (frames[lag:] - mu)).mean()
        assert cov / var == pytest.approx(np.exp(-lag / tau_c), abs=0.035), lag


def _half_width(grid: np.ndarray) -> float:
    """Radius where the normalised intensity autocovariance falls to 1/2 (grid samples)."""
    centred = grid - grid.mean()
    power = np.abs(np.fft.fft2(centred)) ** 2
    acov = np.fft.ifft2(power).real
    profile = acov[0, :40] / acov[0, 0]
    below = int(np.argmax(profile < 0.5))
    x0, x1, y0, y1 = below - 1, below, profile[below - 1], profile[below]
    return x0 + (y0 - 0.5) / (y0 - y1) * (x1 - x0)


@pytest.mark.parametrize("speckle", [1.5, 2.0, 4.0])
def test_speckle_size_follows_the_pupil(speckle):
    grid = Simulator(make(size=256, speckle=speckle)).next_grid_intensity().astype(np.float64)
    # circular pupil with cut-off 1/(4s) cycles per grid sample: acov = |2 J1(v)/v|²,
    # v = 2π ρ/(4s); half maximum at v = 1.6163
    v = np.linspace(1.0, 2.5, 10001)
    v_half = v[np.argmin(np.abs((2 * j1(v) / v) ** 2 - 0.5))]
    expected = v_half * 4 * speckle / (2 * np.pi)
    assert _half_width(grid) == pytest.approx(expected, rel=0.08)


def test_detector_shot_noise_is_poisson():
    scene = make(size=64, detector={"n_max": 1000, "bits": 16, "quantization": False})
    sim = Simulator(scene)
    flat = np.full((64, 64), 0.5, np.float32)
    sim.detect(np.ones((64, 64), np.float32))  # first frame sets the gain: 1.0 -> n_max photons
    grey = np.stack([sim.detect(flat) for _ in range(20)]).astype(np.float64)
    k = 65535 / (1000 + np.sqrt(1000))  # grey levels per photon
    assert grey.mean() / k == pytest.approx(500, rel=0.01)
    assert grey.var() / k**2 == pytest.approx(500, rel=0.04)  # Poisson: variance = mean


def test_ambient_light_adds_poisson_photons_pixel_by_pixel():
    base = {"detector": {"n_max": 1000, "bits": 16, "quantization": False}}
    truth = Simulator(make(size=64, **base))
    noisy = Simulator(make(size=64, ambient_light={"eta": 0.2}, **base))
    k = 65535 / (1000 + np.sqrt(1000))
    pairs = [(noisy.next_frame(), truth.next_frame()) for _ in range(10)]
    # pixels pushed over the range N_max + sqrt(N_max) by the ambient light are clipped
    extra = np.concatenate([(n - t)[n < 65535] for n, t in pairs]).astype(np.float64) / k
    # the ground-truth draws are untouched, the difference is exactly the ambient photons
    assert np.allclose(extra, np.rint(extra), atol=1e-3)
    assert extra.min() >= 0
    assert extra.mean() == pytest.approx(200, rel=0.01)
    assert extra.var() == pytest.approx(200, rel=0.05)


@pytest.mark.parametrize("bits,dtype", [(8, np.uint8), (12, np.uint16), (16, np.uint16)])
def test_quantization_range(bits, dtype):
    frames = list(simulate(make(size=64, frames=5, detector={"n_max": 1000, "bits": bits})))
    top = 2**bits - 1
    first = frames[0]
    assert first.dtype == dtype
    assert int(max(f.max() for f in frames)) <= top
    # the brightest pixel of frame 0 carries ~N_max photons; the range is N_max + sqrt(N_max)
    assert first.max() == pytest.approx(top * 1000 / (1000 + np.sqrt(1000)), rel=0.1)
    assert (first == top).mean() < 1e-3


def test_without_detector_frames_are_float_intensities():
    frames = list(simulate(make(size=32, frames=3)))
    assert len(frames) == 3 and frames[0].dtype == np.float32
    double = list(simulate(make(size=32, frames=3), precision="double"))
    assert double[0].dtype == np.float64
    # single and double precision share every random draw: they differ by rounding only
    assert np.allclose(frames[2], double[2], rtol=1e-4, atol=1e-4)


def test_phase_noise_white_reduces_correlation_by_exp_minus_two_sigma_squared():
    alpha, tau_noise = 0.3, 1.0
    sim = Simulator(make(size=64, tau_c=1e9, phase_noise={"alpha": alpha, "tau_noise": tau_noise}))
    frames = np.stack([sim.next_intensity() for _ in range(120)]).astype(np.float64)[1:]
    mu, var = frames.mean(), frames.var()
    sigma2 = alpha**2 / tau_noise
    for lag in (1, 10):
        cov = ((frames[:-lag] - mu) * (frames[lag:] - mu)).mean()
        assert cov / var == pytest.approx(np.exp(-2 * sigma2), abs=0.03)


def test_ou_phase_noise_decorrelates_with_tau_noise():
    alpha, tau_noise = 1.0, 5.0
    sim = Simulator(make(size=64, tau_c=1e9, phase_noise={"alpha": alpha, "tau_noise": tau_noise,
                                                          "model": "ou"}))
    frames = np.stack([sim.next_intensity() for _ in range(400)]).astype(np.float64)[1:]
    mu, var = frames.mean(), frames.var()
    sigma2 = alpha**2 / tau_noise  # stationary variance of ψ
    for lag in (1, 5, 30):
        # ψ(t+τ)-ψ(t) has variance 2σ²(1-exp(-τ/τ_noise)); intensity corr = exp(-that)
        expected = np.exp(-2 * sigma2 * (1 - np.exp(-lag / tau_noise)))
        cov = ((frames[:-lag] - mu) * (frames[lag:] - mu)).mean()
        assert cov / var == pytest.approx(expected, abs=0.04), lag


def test_drying_slows_the_fluctuation():
    scene = scene_from_dict({"scene": {"size": 64, "seed": 2}, "activity": {
        "tau_c": 2.0, "drying": {"law": "exponential", "start": 0, "duration": 200, "final_factor": 100}}})
    sim = Simulator(scene)
    frames = np.stack([sim.next_intensity() for _ in range(300)]).astype(np.float64)
    early = np.abs(np.diff(frames[:50], axis=0)).mean()
    late = np.abs(np.diff(frames[250:], axis=0)).mean()
    assert late < 0.35 * early


def test_gaussian_illumination_profile():
    scene = make(size=128, illumination={"kind": "gaussian", "omega": 40.0})
    sim = Simulator(scene)
    mean = np.mean([sim.next_intensity() for _ in range(30)], axis=0)
    r = np.hypot(*np.meshgrid(np.arange(128) - 63.5, np.arange(128) - 63.5))
    ring = (r > 38) & (r < 42)
    centre = r < 8
    # I0 = exp(-r²/Ω²): at r = Ω the mean intensity is 1/e of the centre
    assert mean[ring].mean() / mean[centre].mean() == pytest.approx(np.exp(-1), rel=0.12)


def test_same_seed_same_frames_and_reset():
    scene = make(size=32, phase_noise={"alpha": 0.2}, detector={}, ambient_light={"eta": 0.1})
    a = list(simulate(scene))
    sim = Simulator(scene)
    b = list(sim.frames())
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    sim.reset()
    assert np.array_equal(sim.next_frame(), a[0])


def test_laser_off_gives_ambient_only_frames():
    sim = Simulator(make(size=32, detector={"n_max": 1000}, ambient_light={"eta": 0.2}))
    sim.next_frame()
    dark = sim.next_frame(laser_on=False).astype(np.float64)
    k = 255 / (1000 + np.sqrt(1000))
    assert dark.mean() == pytest.approx(200 * k, rel=0.02)
    assert dark.std() == pytest.approx(np.sqrt(200) * k, rel=0.15)


def test_frames_are_produced_one_at_a_time():
    generator = simulate(make(size=32, frames=10**7))  # would need 40 GB if materialised
    first = next(generator)
    assert first.shape == (32, 32)


def test_walk_phase_noise_decorrelates_like_extra_activity():
    alpha, tau_noise = 0.3, 1.0
    sim = Simulator(make(size=64, tau_c=1e9, phase_noise={"alpha": alpha, "tau_noise": tau_noise,
                                                          "model": "walk"}))
    frames = np.stack([sim.next_intensity() for _ in range(300)]).astype(np.float64)
    mu, var = frames.mean(), frames.var()
    for lag in (2, 5, 10):
        # ψ(t+τ)-ψ(t) has variance τ·α²/τ_noise: ρ(τ) = exp(-τ α²/τ_noise), a τc of τ_noise/α²
        cov = ((frames[:-lag] - mu) * (frames[lag:] - mu)).mean()
        assert cov / var == pytest.approx(np.exp(-lag * alpha**2 / tau_noise), abs=0.035), lag
