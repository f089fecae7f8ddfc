"""τc's default longest lag (N/2, issue 23 item 4): the multi-tau lags grow as log K, slow decays
are measured instead of read "above", "above" only beyond K, and pure noise never reads as a τc."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edgedsm.errors import EstimatorError
from edgedsm.estimators import SlidingWindow, tau_c_bounds
from edgedsm.estimators.correlation_time import (
    ABOVE,
    BELOW,
    MEASURED,
    NO_SIGNAL,
    default_max_lag,
    max_lag_problem,
    tau_lags,
)


def _speckle(count: int, size: int, tau: float, seed: int, mean: float = 60.0) -> np.ndarray:
    """Intensity of a complex Gaussian AR(1) field per pixel: ρ(k) = exp(-k/τ), 8 bits."""
    rng = np.random.default_rng(seed)
    r = math.exp(-1 / (2 * tau))
    field = rng.standard_normal((2, size, size))
    frames = np.empty((count, size, size), np.uint8)
    for t in range(count):
        field = r * field + math.sqrt(1 - r * r) * rng.standard_normal((2, size, size))
        frames[t] = np.clip((field**2).sum(axis=0) * mean / 2, 0, 255)
    return frames


def test_the_default_reaches_half_the_window_with_logarithmically_many_lags() -> None:
    assert [default_max_lag(n) for n in (3, 4, 40, 200, 1001)] == [1, 2, 20, 100, 500]
    counts = {k: tau_lags(k).size for k in (20, 100, 500, 5000)}
    assert counts == {20: 9, 100: 14, 500: 18, 5000: 25}  # + about 5 lags per decade of K
    engine = SlidingWindow((8, 8), 200, 10, estimators=("s1", "tau_c"))
    assert engine.max_lag == 100 and list(engine.tau_lags[-3:]) == [57, 80, 100]


def test_one_rule_for_the_longest_lag() -> None:
    assert max_lag_problem(18, 20) is None and "need 1 <= K <= N-2" in max_lag_problem(19, 20)
    with pytest.raises(EstimatorError, match="max_lag K=19 does not fit a window of N=20"):
        SlidingWindow((4, 4), 20, 2, estimators=("tau_c",), max_lag=19)
    with pytest.raises(EstimatorError, match="max_lag K=19 does not fit a window of N=20"):
        tau_c_bounds(np.zeros((20, 4, 4), np.uint8), max_lag=19)


def test_a_slow_decay_is_measured_with_the_default_and_only_a_bound_with_k_20() -> None:
    frames = _speckle(400, 24, tau=60.0, seed=2)
    mask = np.ones((24, 24), bool)
    short = tau_c_bounds(frames, max_lag=20, mask=mask)
    full = tau_c_bounds(frames, max_lag=default_max_lag(400), mask=mask)
    assert short == (20.0, ABOVE)
    assert full.status == MEASURED and 40 < full.tau < 90


def test_above_only_when_tau_exceeds_the_longest_lag() -> None:
    mask = np.ones((24, 24), bool)
    beyond = tau_c_bounds(_speckle(200, 24, tau=600.0, seed=3), max_lag=100, mask=mask)
    assert beyond == (100.0, ABOVE)
    within = tau_c_bounds(_speckle(200, 24, tau=30.0, seed=4), max_lag=100, mask=mask)
    assert within.status == MEASURED and 20 < within.tau < 45


@pytest.mark.parametrize("bits", [8, 12, 16])
@pytest.mark.parametrize("mean", [0.2, 3.0, 40.0, 900.0])
def test_pure_noise_is_never_a_tau(bits: int, mean: float) -> None:
    # temporal shot noise on a static speckle pattern (what a dry, still surface gives), at the
    # default K = N/2: the region reads BELOW, and no more pixels than the 2σ criterion lets
    # through read a number
    rng = np.random.default_rng(int(bits * 10 + mean))
    top = 2**bits - 1
    pattern = rng.exponential(min(mean, top / 8), size=(32, 32))
    frames = np.clip(rng.poisson(pattern, size=(200, 32, 32)), 0, top).astype(np.uint8 if bits <= 8 else np.uint16)
    k = default_max_lag(200)
    region = tau_c_bounds(frames, max_lag=k, mask=np.ones((32, 32), bool))
    assert region.status in (BELOW, NO_SIGNAL) and region.tau in (1 / 3, 0.0)
    per_pixel = tau_c_bounds(frames, max_lag=k)
    assert np.isin(per_pixel.status, (BELOW, NO_SIGNAL, MEASURED, ABOVE)).all()
    assert np.mean(per_pixel.status == MEASURED) + np.mean(per_pixel.status == ABOVE) < 0.05


@pytest.mark.parametrize("bits", [8, 16])
def test_constant_frames_have_no_signal(bits: int) -> None:
    frames = np.full((50, 6, 6), 7, np.uint8 if bits == 8 else np.uint16)
    assert tau_c_bounds(frames, max_lag=default_max_lag(50), mask=np.ones((6, 6), bool)) == (0.0, NO_SIGNAL)


def test_a_darkening_drying_film_keeps_rising_through_its_stages() -> None:
    # config/scenes/darkening_film.toml at 64²: τc 2 -> 200 frames while the light falls to a
    # tenth; disjoint sets of N = 200 frames (docs/tau_c.md, "The longest lag")
    import tomllib
    from pathlib import Path

    from edgedsm.sim import Simulator, scene_from_dict
    from edgedsm.timeline import timeline

    path = Path(__file__).parents[3] / "config" / "scenes" / "darkening_film.toml"
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    data["scene"]["size"] = 64
    frames = list(Simulator(scene_from_dict(data)).frames(1200))
    regions = {"film": np.ones((64, 64), bool)}
    full = timeline(iter(frames), regions, 200, 5, 200, max_lag=default_max_lag(200), bits=8)
    short = timeline(iter(frames), regions, 200, 5, 200, max_lag=20, bits=8)
    taus, statuses = full.series("film", "tau_c_frames"), [row[8] for row in full.rows]
    assert statuses == ["measured"] * 5 + ["above"]  # the last set's τc (126…200) is beyond N/2
    assert np.all(np.diff(taus[:5]) > 0) and 1.5 < taus[0] < 3 and 50 < taus[4] < 100
    assert [row[8] for row in short.rows][3:] == ["above"] * 3


def test_the_batch_functions_default_to_the_daemons_k_of_half_the_window() -> None:
    """tau_c and tau_c_bounds without max_lag use N/2 as the daemon and the engine do (they used
    20): a τc = 40 decay at N = 200 is measured, where K = 20 reads only "above 20"."""
    from edgedsm.estimators import tau_c
    from edgedsm.estimators.correlation_time import covariances

    frames = _speckle(200, 24, 40.0, seed=7)
    region = np.ones(frames.shape[1:], bool)
    default = tau_c_bounds(frames, mask=region)
    assert tuple(default) == tuple(tau_c_bounds(frames, 100, mask=region))
    assert default.status == MEASURED and 20 < default.tau < 100
    assert tuple(tau_c_bounds(frames, 20, mask=region)) == (20.0, ABOVE)
    np.testing.assert_array_equal(tau_c(frames[:40]), tau_c(frames[:40], default_max_lag(40)))
    assert covariances(frames[:40])[0].shape[0] == tau_lags(20).size  # N = 40: K = 20
    engine = SlidingWindow(frames.shape[1:], 200, 10, estimators=("s1", "tau_c"))
    for frame in frames:
        engine.push(frame)
    assert engine.max_lag == 100 and engine.region_tau_c(region).tau == pytest.approx(default.tau, rel=1e-9)
    with pytest.raises(EstimatorError, match="max_lag K=1 does not fit a window of N=2"):
        tau_c(frames[:2])  # N/2 = 1 does not fit N = 2: the same refusal as an explicit K
