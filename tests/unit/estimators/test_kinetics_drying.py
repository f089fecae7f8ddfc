"""The time-resolved correlation on a simulated film drying over four decades (τc 2 -> 20,000
frames, ``[activity.drying]``): τ(t) follows the scene's truth where the truth is within the
longest age, and says ``above`` beyond it, while the window τc of the same frames saturates."""

from __future__ import annotations

import numpy as np
import pytest

from edgedsm.estimators.correlation_time import ABOVE as WINDOW_ABOVE
from edgedsm.estimators.correlation_time import tau_c_bounds
from edgedsm.estimators.kinetics import ABOVE, OK, Kinetics
from edgedsm.estimators.noise import NoiseModel
from edgedsm.sim import Simulator, scene_from_dict
from edgedsm.sim.activity import decorrelation_lags
from edgedsm.sim.detector import DetectorRows

SIZE, FRAMES, LONGEST, STRIDE = 32, 16_000, 1024, 20
WINDOW, MAX_LAG = 128, 64


@pytest.mark.compute
@pytest.mark.slow
@pytest.mark.timeout(240)
def test_tau_follows_a_film_drying_over_four_decades() -> None:
    film = scene_from_dict({"scene": {"size": SIZE, "seed": 11},
                            "activity": {"tau_c": 2.0, "drying": {"duration": FRAMES, "final_factor": 1e4}},
                            "detector": {"n_max": 1000.0, "bits": 8}})
    camera = NoiseModel(gain=DetectorRows(film).scale)  # the simulator's grey levels per photon
    mask = np.ones((SIZE, SIZE), bool)
    kinetics = Kinetics(mask, camera, LONGEST)
    simulator = Simulator(film)
    samples, taus, statuses, window = [], [], [], []
    recent: list[np.ndarray] = []
    for index in range(FRAMES):
        frame = simulator.next_frame()
        kinetics.push(frame)
        recent = [*recent[-(WINDOW - 1):], frame]
        if index % STRIDE == 0 and index > 0:
            result = kinetics.measure()
            samples.append(index)
            taus.append(np.nan if result.tau is None else result.tau)
            statuses.append(result.status)
        if index in (FRAMES // 4, FRAMES // 2, FRAMES - 1):
            window.append(tau_c_bounds(np.stack(recent), MAX_LAG, mask))
    truth = decorrelation_lags(film, np.array(samples))
    tau = np.array(taus)
    inside = (truth >= 1.0) & (truth <= LONGEST)
    assert truth[inside].min() < 3.0 and truth[inside].max() > 0.9 * LONGEST  # the run spans the decades
    error = np.where(np.isfinite(tau[inside]), np.abs(tau[inside] / truth[inside] - 1.0), np.inf)
    assert np.median(error) < 0.25
    assert np.mean([statuses[i] == OK for i in np.flatnonzero(inside)]) > 0.95
    for low in (1.0, 10.0, 100.0):  # every decade, not just the run's median
        decade = inside & (truth >= low) & (truth < 10.0 * low)
        assert abs(np.nanmedian(tau[decade] / truth[decade]) - 1.0) < 0.25, low
    beyond = truth > 1.2 * LONGEST
    assert beyond.sum() > 20 and np.mean([statuses[i] == ABOVE for i in np.flatnonzero(beyond)]) > 0.95
    # the window estimator of the same frames: measured early, saturated "above K" late
    assert window[0].status != WINDOW_ABOVE and window[0].tau < MAX_LAG
    assert window[-1].status == WINDOW_ABOVE and window[-1].tau == MAX_LAG


@pytest.mark.compute
@pytest.mark.slow
@pytest.mark.timeout(240)
def test_white_phase_noise_shortens_tau_unless_taken_out() -> None:
    """The simulator's white phase noise (α = 0.3 rad a frame) lowers every pair's correlation by
    exp(-2·0.09): τ reads about 18 % short; measure(white=True) takes the step out."""
    frames = 6000
    film = scene_from_dict({"scene": {"size": SIZE, "seed": 12},
                            "activity": {"tau_c": 2.0, "drying": {"duration": frames, "final_factor": 300.0}},
                            "phase_noise": {"alpha": 0.3, "tau_noise": 1.0, "model": "white"},
                            "detector": {"n_max": 1000.0, "bits": 8}})
    kinetics = Kinetics(np.ones((SIZE, SIZE), bool), NoiseModel(gain=DetectorRows(film).scale), LONGEST)
    simulator = Simulator(film)
    samples, plain, white = [], [], []
    for index in range(frames):
        kinetics.push(simulator.next_frame())
        if index % STRIDE == 0 and index > 0:
            samples.append(index)
            plain.append(kinetics.measure().tau or np.nan)
            white.append(kinetics.measure(white=True).tau or np.nan)
    truth = decorrelation_lags(film, np.array(samples))
    inside = (truth >= 1.0) & (truth <= LONGEST)
    assert abs(np.nanmedian(np.array(plain)[inside] / truth[inside]) - 0.82) < 0.06
    assert abs(np.nanmedian(np.array(white)[inside] / truth[inside]) - 1.0) < 0.08
