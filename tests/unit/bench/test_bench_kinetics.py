"""The kinetics benchmark (edgedsm_lab/bench/kinetics.py) on a tiny film: its runs, scores, tables,
figure and cost."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edgedsm_lab.bench import kinetics as bench
from edgedsm_lab.bench.report import Report

TINY = bench.Case(size=24, frames=2500, final_factor=1e3, longest_age=256, stride=10, window=64, max_lag=16,
                  window_every=400, variants=("plain", "darkening to 0.1"))


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_a_tiny_film_is_scored_drawn_and_costed(tmp_path) -> None:
    result = bench.measure(TINY)
    assert list(result.runs) == list(TINY.variants)
    plain = result.runs["plain"]
    assert plain.frames.size == (TINY.frames - 1) // TINY.stride
    assert plain.truth.shape == plain.tau.shape == plain.tau_plain.shape == plain.tau_white.shape
    score = bench.score(plain.truth, plain.tau, TINY.longest_age)
    assert score.samples > 100 and score.median_error < 0.25 and score.share_ok > 0.9
    assert score.truth_low < 3.0
    # the window τc of the same frames: measured while the film is fast, "above K" once it is slow
    assert plain.window_status[0] == bench.WINDOW_MEASURED and plain.window_status[-1] == bench.WINDOW_ABOVE
    assert "above K = 16 from frame" in bench.window_summary(plain, TINY.max_lag)
    # the darkening film is a different film: a different scene, another τ
    assert not np.array_equal(result.runs["darkening to 0.1"].tau, plain.tau, equal_nan=True)
    report = Report("kinetics", echo=lambda _line: None)
    bench.report_lines(result, report)
    text = "\n".join(report.lines)
    assert "| plain | kinetics |" in text and "| darkening to 0.1 | Eq. 1 unflattened |" in text
    assert "| plain | kinetics, white step out |" in text
    figure = tmp_path / "kinetics.png"
    bench.draw(result, figure)
    assert figure.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    spent = bench.cost(size=48, longest_age=64, repeats=3, window=16)
    assert all(spent[key] > 0 and math.isfinite(spent[key]) for key in ("s1", "default", "push", "measure"))
    assert spent["bytes_per_pixel"] == 4 * (spent["slots"] + 1)
    rows = bench.cost_rows(spent)
    assert [row[0][:13] for row in rows] == ["S1 push", "default push ", "kinetics push", "kinetics push",
                                             "kinetics meas", "kinetics push", "kinetics meas", "kinetics push",
                                             "kinetics meas"]
    assert rows[0][2] == "1.00"


def test_a_score_counts_a_missing_number_as_a_miss() -> None:
    truth = np.array([0.5, 2.0, 4.0, 8.0, 5000.0])
    tau = np.array([0.4, 2.2, np.nan, 8.0, 10.0])
    score = bench.score(truth, tau, 4096)
    assert score.samples == 3  # truth below a frame and beyond the longest age are left out
    assert score.median_error == pytest.approx(0.1)  # errors 0.1, inf, 0
    assert score.share_ok == pytest.approx(2 / 3)
    assert score.median_ratio == pytest.approx(1.05)


def test_constant_films_give_tau_c_by_box_and_by_step() -> None:
    from edgedsm_lab.bench import kinetics_films

    films = kinetics_films.Films(frames=400, skip=150, stride=5, box_size=32, step_size=64, longest_age=64)
    by_box = kinetics_films.boxes(films, 5.0)
    by_step = kinetics_films.steps(films, 5.0)
    assert set(by_box) == set(kinetics_films.BOXES) and set(by_step) == set(kinetics_films.STEPS)
    for median, scatter, share in [*by_box.values(), *by_step.values()]:
        assert 0.7 < median < 1.3 and 0.0 < scatter < 0.5 and share > 0.9


def test_the_glue_runner_ranks_stages_of_any_frame_source(tmp_path) -> None:
    """The glue series is not shipped (no licence): its runner on two simulated stages, one fast
    and one slower than the frames, saved as .npy stacks."""
    from edgedsm.sim import Simulator, scene_from_dict
    from edgedsm_lab.bench import kinetics_films

    paths = {}
    for stage, tau in (("10min", 8.0), ("20min", 5000.0)):
        scene = scene_from_dict({"scene": {"size": 48, "seed": 2}, "activity": {"tau_c": tau},
                                 "detector": {"n_max": 1000.0, "bits": 8}})
        simulator = Simulator(scene)
        paths[stage] = tmp_path / f"{stage}.npy"
        np.save(paths[stage], np.stack([simulator.next_frame() for _ in range(64)]))
    rows = kinetics_films.glue({stage: str(path) for stage, path in paths.items()}, channel=None, max_lag=16)
    assert [row[0] for row in rows] == ["10min", "20min"]
    assert 0.7 * 8.0 < float(rows[0][3]) < 1.3 * 8.0 and rows[0][4] == "0%"
    status, bound = rows[1][3].split()
    assert status == "above" and 32 < int(bound) <= 63  # the oldest age kept at the last frame
    assert rows[1][4] == "100%" and rows[1][5] == "16.0 (above K)"
