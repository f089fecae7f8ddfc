"""The truth of a drying scene's decorrelation time (edgedsm.sim.activity.decorrelation_lags)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edgedsm.sim import scene_from_dict
from edgedsm.sim.activity import decorrelation_lags


def scene(drying: dict | None = None, tau_c: float = 2.0):
    activity = {"tau_c": tau_c} | ({"drying": drying} if drying else {})
    return scene_from_dict({"scene": {"size": 32}, "activity": activity})


def test_a_constant_film_decorrelates_in_its_tau_c() -> None:
    frames = np.array([0, 4, 5, 6, 100, 12_345])
    lags = decorrelation_lags(scene(tau_c=5.0), frames)
    assert np.isinf(lags[0]) and np.isinf(lags[1])  # frame 0 is still closer than 1/e
    np.testing.assert_allclose(lags[2:], 5.0, rtol=1e-12)


@pytest.mark.parametrize("law", ["exponential", "linear", "logistic"])
def test_the_lag_integrates_the_simulators_phase_steps_to_one(law: str) -> None:
    """Σ over the frames between t - τ and t of the phase-step variances 1/(τc·factor(i)), the last
    (partial) frame counted by its share, is 1: summed here frame by frame, independently."""
    film = scene({"law": law, "start": 50, "duration": 3000, "final_factor": 1000.0})
    drying = film.activity.drying
    for t in (60, 700, 2000, 3500):
        lag = float(decorrelation_lags(film, np.array([t]))[0])
        start = t - lag
        whole = math.ceil(start)
        total = sum(1.0 / (2.0 * drying.factor(i)) for i in range(whole + 1, t + 1))
        total += (whole - start) / (2.0 * drying.factor(whole))  # the share of frame `whole`'s step
        assert total == pytest.approx(1.0, rel=1e-9)


def test_an_exponential_film_follows_the_continuous_law() -> None:
    """τc = τ0·e^{rt}: ∫_{t-τ}^{t} ds/τc(s) = 1 gives τ = ln(1 + r·τc(t))/r (continuous time)."""
    film = scene({"duration": 60_000, "final_factor": 1e4})
    frames = np.array([1_000, 10_000, 30_000, 50_000])
    rate = math.log(1e4) / 60_000
    expected = np.log1p(rate * 2.0 * 1e4 ** (frames / 60_000)) / rate
    np.testing.assert_allclose(decorrelation_lags(film, frames), expected, rtol=2e-3)
