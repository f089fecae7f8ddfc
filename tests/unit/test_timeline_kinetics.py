"""``analyze --timeline --kinetics`` (issue 37): each region's decorrelation time over decades as
the timeline's last columns, through the measurement core the daemon reads it with; on a film
drying over four decades of τc (2 -> 20,000 frames in 16,000 frames of 32²) it follows the
scene's truth within 25 % (median) below the longest age while the window τc beside it saturates."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from edgedsm.cli import main
from edgedsm.config.kinetics import KineticsSection
from edgedsm.estimators.noise import NoiseModel
from edgedsm.measurement.kinetics import COLUMNS
from edgedsm.sim import Simulator, scene_from_dict
from edgedsm.sim.activity import decorrelation_lags
from edgedsm.sim.detector import DetectorRows
from edgedsm.timeline import timeline

SIZE, FRAMES, DT, LONGEST = 32, 16_000, 0.05, 1024
SCENE = {"scene": {"size": SIZE, "seed": 11, "dt": DT},
         "activity": {"tau_c": 2.0, "drying": {"duration": FRAMES, "final_factor": 1e4}},
         "detector": {"n_max": 1000.0, "bits": 8}}


@pytest.mark.compute
@pytest.mark.slow
@pytest.mark.timeout(240)
def test_the_timeline_follows_a_film_drying_over_four_decades() -> None:
    film = scene_from_dict(SCENE)
    simulator = Simulator(film)
    frames = (simulator.next_frame() for _ in range(FRAMES))
    result = timeline(frames, {"film": np.ones((SIZE, SIZE), bool)}, window=64, lag=1, every=40, dt=DT,
                      max_lag=32, bits=8, with_noise=False, noise_model=NoiseModel(gain=DetectorRows(film).scale),
                      kinetics=KineticsSection(longest_age_s=LONGEST * DT))
    assert result.columns[-len(COLUMNS):] == COLUMNS
    frame = result.series("film", "frame").astype(int)
    tau = result.series("film", "kinetics_tau_s") / DT
    rate = result.series("film", "kinetics_rate_hz")
    status = [row[result.columns.index("kinetics_status")] for row in result.rows]
    truth = decorrelation_lags(film, frame)
    inside = (truth >= 1.0) & (truth <= LONGEST)
    assert truth[inside].min() < 3.0 and truth[inside].max() > 0.9 * LONGEST
    error = np.where(np.isfinite(tau[inside]), np.abs(tau[inside] / truth[inside] - 1.0), np.inf)
    assert np.median(error) < 0.25, np.median(error)
    for low in (1.0, 10.0, 100.0):
        decade = inside & (truth >= low) & (truth < 10.0 * low)
        assert abs(np.nanmedian(tau[decade] / truth[decade]) - 1.0) < 0.25, low
    measured = np.isfinite(tau)
    np.testing.assert_allclose(rate[measured], 1.0 / (tau[measured] * DT), rtol=1e-9)
    beyond = truth > 1.2 * LONGEST
    assert beyond.sum() > 20 and np.mean([status[i] == "above" for i in np.flatnonzero(beyond)]) > 0.95
    bound = result.series("film", "kinetics_bound_s")
    oldest = bound[np.flatnonzero(beyond)]  # above the oldest reference, in s: within 2^(1/4) of the longest age
    assert np.all((oldest >= LONGEST * DT / 2**0.25) & (oldest <= 2**0.25 * LONGEST * DT))
    # the window τc of the same frames (K = 32) beside it: measured while fast, "above" once slow (and
    # once the film is static, beyond the longest age, the window's variance is the camera's white
    # noise: it reads "below"), where the kinetics still measures
    window = [row[result.columns.index("tau_c_status")] for row in result.rows]
    slow = np.flatnonzero((truth > 100) & (truth <= LONGEST))
    assert window[0] == "measured" and np.mean([window[i] == "above" for i in slow]) > 0.9
    assert np.mean([status[i] == "ok" for i in slow]) > 0.95


def test_analyze_writes_the_kinetics_columns(tmp_path: Path) -> None:
    scene = tmp_path / "film.toml"
    scene.write_text("[scene]\nsize = 32\nseed = 4\ndt = 0.05\n[activity]\ntau_c = 6.0\n"
                     "[detector]\nn_max = 1000.0\nbits = 8\n")
    out = tmp_path / "out"
    assert main(["analyze", str(scene), "--frames", "300", "--timeline", str(out), "--window", "50", "--lag", "2",
                 "--every", "50", "--kinetics", "--kinetics-longest-s", "10", "--no-noise-floor"]) == 0
    with (out / "timeline.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert set(COLUMNS) <= set(rows[0]) and len(rows) == 6
    for row in rows:
        assert row["kinetics_status"] == "ok"
        tau_s, rate = float(row["kinetics_tau_s"]), float(row["kinetics_rate_hz"])
        assert tau_s == pytest.approx(6.0 * 0.05, rel=0.3) and rate == pytest.approx(1.0 / tau_s, rel=1e-5)
        assert math.isnan(float(row["kinetics_bound_s"]))
    plain = tmp_path / "plain"
    assert main(["analyze", str(scene), "--frames", "100", "--timeline", str(plain), "--window", "50",
                 "--no-noise-floor"]) == 0
    assert "kinetics_tau_s" not in (plain / "timeline.csv").read_text().splitlines()[0]
    assert main(["analyze", str(scene), "--frames", "100", "--timeline", str(plain), "--window", "50",
                 "--kinetics", "--kinetics-longest-s", "0"]) == 78


def test_a_config_judging_on_the_kinetics_gives_the_timeline_its_activity(tmp_path: Path) -> None:
    scene = tmp_path / "film.toml"
    scene.write_text("[scene]\nsize = 32\nseed = 4\ndt = 0.05\n[activity]\ntau_c = 6.0\n"
                     "[detector]\nn_max = 1000.0\nbits = 8\n")
    config = tmp_path / "daemon.toml"
    config.write_text("[camera]\nuri = 'sim:default'\n[camera.noise]\ngain = 0.247\n[estimator]\n"
                      "activity = 'kinetics'\n[kinetics]\nenabled = true\nlongest_age_s = 10\n"
                      "[[regions]]\nname = 'plate'\nwet_below_s = 0.5\ndry_above_s = 5\n")
    out = tmp_path / "out"
    assert main(["analyze", str(scene), "--frames", "300", "--timeline", str(out), "--window", "50", "--lag", "2",
                 "--every", "50", "-c", str(config)]) == 0  # no --kinetics: the config judges on it
    with (out / "timeline.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    for row in rows:
        assert row["estimator"] == "kinetics" and row["kinetics_status"] == "ok"
        assert float(row["activity"]) == float(row["kinetics_tau_s"]) == pytest.approx(0.3, rel=0.3)


def test_timeline_png_draws_the_kinetics_beside_tau_c() -> None:
    from edgedsm.commands.timeline_output import activity_figure

    film = scene_from_dict({"scene": {"size": SIZE, "seed": 4, "dt": DT}, "activity": {"tau_c": 6.0},
                            "detector": {"n_max": 1000.0, "bits": 8}})
    simulator = Simulator(film)
    result = timeline((simulator.next_frame() for _ in range(200)), {"film": np.ones((SIZE, SIZE), bool)},
                      window=50, lag=2, every=50, dt=DT, bits=8, with_noise=False,
                      kinetics=KineticsSection(longest_age_s=10.0))
    figure = activity_figure(result, "film")
    tau_axis = figure.axes[-1]
    lines = {line.get_label(): line for line in tau_axis.get_lines()}
    assert "film τ (kinetics)" in lines and tau_axis.get_yscale() == "log"
    np.testing.assert_allclose(lines["film τ (kinetics)"].get_ydata(), result.series("film", "kinetics_tau_s"))
    assert tau_axis.get_ylabel() == "τc, τ (kinetics) (s)"
