"""The simulator's fast paths compute the same model: pruned FFT, threaded blocks and sub-streams,
Box-Muller normals, single/double sharing their draws, and the Poisson samplers of the detector."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chisquare
from scipy.stats import poisson as poisson_dist

from edgedsm.sim import Simulator, scene_from_dict
from edgedsm.sim import poisson as poisson_module
from edgedsm.sim import simulator as simulator_module
from edgedsm.sim.optics import pupil_transfer
from edgedsm.sim.poisson import ConstantPoisson, counter_uniforms, poisson

ALL_EFFECTS = {
    "illumination": {"kind": "gaussian", "omega": 40.0},
    "phase_noise": {"alpha": 0.3, "tau_noise": 3.0, "model": "ou"},
    "ambient_light": {"eta": 0.2},
    "detector": {"n_max": 1000, "bits": 12},
}


def make(size: int = 64, speckle: float = 2.0, seed: int = 3, **tables) -> object:
    data = {"scene": {"size": size, "seed": seed, "speckle_size": speckle},
            "activity": {"tau_c": 20.0, "drying": {"duration": 50, "final_factor": 4.0}}}
    data.update(tables)
    return scene_from_dict(data)


# -- propagation -------------------------------------------------------------------------------
@pytest.mark.parametrize("size,speckle", [(64, 2.0), (100, 1.5), (50, 3.3), (64, 0.5), (128, 4.0)])
@pytest.mark.parametrize("precision,tolerance", [("single", 2e-5), ("double", 1e-12)])
def test_pruned_propagation_equals_full_fft2(size, speckle, precision, tolerance):
    sim = Simulator(make(size, speckle), precision=precision)
    rng = np.random.default_rng(0)
    amplitude = rng.random((2 * size, 2 * size)) + 0.5
    field = amplitude * np.exp(-2j * np.pi * rng.random((2 * size, 2 * size)))
    pupil = pupil_transfer(size, speckle, np.float64)
    reference = np.abs(np.fft.ifft2(pupil * np.fft.fft2(field))) ** 2
    got = sim._propagate(field)
    assert got.dtype == (np.float32 if precision == "single" else np.float64)
    assert np.abs(got - reference).max() <= tolerance * reference.mean()


def test_pruning_is_used_where_it_saves_work():
    assert Simulator(make(64, 2.0))._band_k == 16  # radius size/(2s): 33 of 128 columns
    assert Simulator(make(64, 0.5))._band_k is None  # the pupil fills the spectrum


def test_band_limit_matches_the_pupil():
    pupil = pupil_transfer(100, 1.5, np.float64)
    k = simulator_module._band_limit(pupil)
    freq = np.abs(np.fft.fftfreq(200) * 200)
    assert k is not None
    assert pupil[:, freq > k].max() == 0 and pupil[:, freq == k].max() > 0


# -- threads and sub-streams -------------------------------------------------------------------
@pytest.mark.parametrize("size", [64, 100, 160])
def test_frames_do_not_depend_on_the_thread_count(size):
    sims = [Simulator(make(size, **ALL_EFFECTS), workers=w) for w in (1, 2, 3)]
    assert sims[0]._blocks > 1 or size == 64
    for _ in range(4):
        frames = [sim.next_frame() for sim in sims]
        assert all(np.array_equal(frames[0], other) for other in frames[1:])
    grids = [sim.next_grid_intensity() for sim in sims]
    assert all(np.array_equal(grids[0], other) for other in grids[1:])
    states = [{name: rng.bit_generator.state for name, rng in sim.rngs.items()} for sim in sims]
    assert states[0] == states[1] == states[2]


def test_blocks_cover_the_grid_with_even_rows():
    for grid in (32, 200, 512, 1024, 2048, 16384):
        rows = simulator_module._block_rows(grid)
        assert rows % 2 == 0 and 2 <= rows <= grid
        assert rows * grid <= max(simulator_module._BLOCK_POINTS, 2 * grid)


def test_substreams_start_with_the_effect_stream_and_differ():
    root = np.random.default_rng(7)
    first = root.bit_generator.state
    streams = simulator_module._substreams(root, 4)
    assert streams[0] is root and root.bit_generator.state == first
    draws = [s.random(4) for s in streams]
    assert len({d.tobytes() for d in draws}) == 4


def test_next_frame_detects_as_detect_of_next_intensity():
    fused, plain = Simulator(make(100, **ALL_EFFECTS)), Simulator(make(100, **ALL_EFFECTS))
    for laser_on in (True, True, False, True):
        assert np.array_equal(fused.next_frame(laser_on), plain.detect(plain.next_intensity(), laser_on))


# -- normals and precision ---------------------------------------------------------------------
@pytest.mark.parametrize("precision", ["single", "double"])
def test_box_muller_normals_are_standard_normal(precision):
    sim = Simulator(make(256), precision=precision)
    scratch = sim._scratch_for(0)
    rng = np.random.default_rng(11)
    z = np.concatenate([sim._normals(rng, scratch.normals, scratch).ravel().astype(np.float64).copy()
                        for _ in range(64)])
    assert z.size >= 2**21
    assert abs(z.mean()) < 0.004
    assert z.var() == pytest.approx(1.0, abs=0.004)
    assert (z**4).mean() == pytest.approx(3.0, abs=0.03)
    for t, tail in ((1.0, 0.31731), (2.0, 0.04550), (3.0, 0.0026998)):
        assert (np.abs(z) > t).mean() == pytest.approx(tail, rel=0.05)
    assert np.isfinite(z).all()


def test_single_and_double_share_their_draws():
    single = Simulator(make(64, **ALL_EFFECTS), precision="single")
    double = Simulator(make(64, **ALL_EFFECTS), precision="double")
    for _ in range(40):
        a, b = single.next_intensity().astype(np.float64), double.next_intensity()
        assert np.sqrt(((a - b) ** 2).mean()) < 1e-5 * b.std()
    differ = [np.mean(single.next_frame() != double.next_frame()) for _ in range(20)]
    assert np.mean(differ) < 1e-3  # a count changes only where rounding decides a draw


# -- Poisson samplers --------------------------------------------------------------------------
def _chi_square_p(counts: np.ndarray, lam: float) -> float:
    k = np.arange(int(lam + 10 * np.sqrt(lam) + 10))
    observed = np.bincount(counts.astype(np.int64), minlength=k.size)[:k.size]
    expected = poisson_dist.pmf(k, lam) * counts.size
    keep = expected > 5
    return float(chisquare(observed[keep], expected[keep] * observed[keep].sum() / expected[keep].sum()).pvalue)


KERNELS = ["numpy", pytest.param("numba", marks=pytest.mark.skipif(
    poisson_module._numba() is None, reason="numba not installed"))]


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("lam", [0.3, 4.0, 9.99, 10.0, 37.5, 1000.0])
def test_poisson_counts_follow_the_poisson_law(kernel, lam):
    counts = poisson(np.random.default_rng(int(lam * 100)), lam, (400_000,), kernel=kernel)
    assert counts.dtype == np.float64 and (counts == np.rint(counts)).all() and counts.min() >= 0
    assert counts.mean() == pytest.approx(lam, rel=0.01)
    assert counts.var() == pytest.approx(lam, rel=0.02)
    assert _chi_square_p(counts, lam) > 1e-3  # fixed seeds: a deterministic check


@pytest.mark.parametrize("kernel", KERNELS)
def test_poisson_per_pixel_rates(kernel):
    rates = np.tile(np.array([0.0, 2.5, 10.0, 180.0]), 100_000).reshape(400, 1000)
    counts = poisson(np.random.default_rng(2), rates, kernel=kernel)
    assert counts.shape == rates.shape
    assert (counts[rates == 0] == 0).all()
    for lam in (2.5, 10.0, 180.0):
        assert _chi_square_p(counts[rates == lam], lam) > 1e-3


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("lam", [10.0, 200.0, 5e4])
def test_constant_poisson_alias_table(kernel, lam):
    sampler = ConstantPoisson(lam, kernel=kernel)
    assert sampler.table is not None
    counts = sampler.draw(np.random.default_rng(4), (500, 800))
    assert counts.shape == (500, 800)
    assert counts.mean() == pytest.approx(lam, rel=0.005)
    assert counts.var() == pytest.approx(lam, rel=0.02)
    if lam < 1000:
        assert _chi_square_p(counts.ravel(), lam) > 1e-3


def test_constant_poisson_without_table_falls_back():
    assert ConstantPoisson(3.0).table is None and ConstantPoisson(1e8).table is None
    counts = ConstantPoisson(1e8).draw(np.random.default_rng(1), (100_000,))
    assert counts.mean() == pytest.approx(1e8, rel=1e-4)
    assert counts.var() == pytest.approx(1e8, rel=0.03)


@pytest.mark.skipif(poisson_module._numba() is None, reason="numba not installed")
def test_numba_and_numpy_kernels_give_the_same_counts():
    rates = np.random.default_rng(0).exponential(100.0, (300, 300))
    rates[:10] = 0.0
    a = poisson(np.random.default_rng(9), rates, kernel="numba")
    b = poisson(np.random.default_rng(9), rates, kernel="numpy")
    assert np.array_equal(a, b)
    for lam in (200.0, 3.0):
        a = ConstantPoisson(lam, "numba").draw(np.random.default_rng(9), (300, 300))
        b = ConstantPoisson(lam, "numpy").draw(np.random.default_rng(9), (300, 300))
        assert np.array_equal(a, b)


@pytest.mark.skipif(poisson_module._numba() is None, reason="numba not installed")
def test_simulator_without_numba_gives_the_same_frames(monkeypatch):
    with_numba = [f.copy() for f in Simulator(make(100, **ALL_EFFECTS)).frames(4)]
    monkeypatch.setattr(poisson_module, "_numba_module", None)
    without = list(Simulator(make(100, **ALL_EFFECTS)).frames(4))
    assert all(np.array_equal(a, b) for a, b in zip(with_numba, without, strict=True))


def test_poisson_takes_a_fixed_number_of_draws():
    rates = np.random.default_rng(0).exponential(50.0, 10_000)
    rng = np.random.default_rng(5)
    poisson(rng, rates)
    reference = np.random.default_rng(5)
    reference.bit_generator.advance(2 * rates.size + 1)
    assert rng.bit_generator.state == reference.bit_generator.state


def test_a_tiny_change_of_rate_changes_few_counts():
    rates = np.random.default_rng(0).exponential(100.0, 200_000)
    a = poisson(np.random.default_rng(1), rates)
    b = poisson(np.random.default_rng(1), rates * (1 + 1e-7))
    assert np.mean(a != b) < 1e-3


def test_counter_uniforms_are_uniform_and_positional():
    key = np.uint64(12345)
    u = counter_uniforms(key, np.arange(1_000_000, dtype=np.uint64))
    assert u.min() >= 0.0 and u.max() < 1.0
    assert u.mean() == pytest.approx(0.5, abs=2e-3) and u.var() == pytest.approx(1 / 12, rel=5e-3)
    assert np.abs(np.corrcoef(u[:-1], u[1:])[0, 1]) < 5e-3
    picked = np.array([5, 999_999, 17], dtype=np.uint64)
    assert np.array_equal(counter_uniforms(key, picked), u[picked.astype(np.intp)])


def test_poisson_rejects_bad_rates():
    with pytest.raises(ValueError):
        poisson(np.random.default_rng(), np.array([1.0, -1.0]))
    with pytest.raises(ValueError):
        poisson(np.random.default_rng(), np.array([np.nan]))
    with pytest.raises(ValueError):
        poisson(np.random.default_rng(), 3.0)  # a constant needs a shape
    with pytest.raises(ValueError):
        ConstantPoisson(-2.0)
