"""The drying stages in the timeline (issue 37): ``analyze --timeline --kinetics -c CONFIG`` with
``[[kinetics.stages]]`` writes per region and sample the stage reached, when, the next stage and
the time to it, through edgedsm/measurement/stages.py (the daemon's code). Checked against the
kinetics columns of the same CSV: a stage is reached at the first sample of the run of samples whose
τ is at or above the stage's (rate at or below its threshold) for the dwell, in order."""

from __future__ import annotations

import csv
import math
from pathlib import Path

from edgedsm.cli import main
from edgedsm.measurement.stages import COLUMNS

REPO = Path(__file__).resolve().parents[2]
DT = 0.05
STAGES = {"set_to_touch": 2.0, "tack_free": 0.2}  # Hz: τ 0.5 s (10 frames) and 5 s (100 frames)
DWELL_S = 2.0


def _reached(rows: list[dict[str, str]], rate_hz: float, after: float) -> float | None:
    """The first sample time (after ``after``) starting a run of readings at or below ``rate_hz``
    that lasts the dwell (readings without a number neither extend nor break a run)."""
    since = None
    for row in rows:
        t = float(row["time_s"])
        if row["kinetics_status"] == "ok":
            rate = float(row["kinetics_rate_hz"])
        elif row["kinetics_status"] == "above":
            rate = 1.0 / float(row["kinetics_bound_s"])
        elif row["kinetics_status"] == "below":
            rate = math.inf
        else:
            continue
        if rate > rate_hz:
            since = None
            continue
        since = t if since is None else since
        if t - since >= DWELL_S and since >= after:
            return since
    return None


def test_the_timeline_writes_each_regions_stage_and_the_time_to_the_next(tmp_path: Path) -> None:
    scene = tmp_path / "plate.toml"  # τc 3 -> 300 frames between 10 s and 50 s
    scene.write_text((REPO / "config" / "scenes" / "drying_demo.toml").read_text().replace("size = 128", "size = 48"))
    stages = "".join(f"[[kinetics.stages]]\nname = '{name}'\nrate_below_hz = {rate}\n" for name, rate in STAGES.items())
    config = tmp_path / "daemon.toml"
    config.write_text("[camera]\nuri = 'sim:default'\n[kinetics]\nlongest_age_s = 60\n"
                      f"stage_dwell_s = {DWELL_S}\ntrend_window_s = 10\n{stages}"
                      "[[regions]]\nname = 'plate'\nwet_above = 0.3\ndry_below = 0.1\n")
    out = tmp_path / "out"
    assert main(["analyze", str(scene), "--frames", "1300", "--timeline", str(out), "--window", "50", "--lag", "2",
                 "--every", "10", "--kinetics", "-c", str(config), "--no-progress"]) == 0
    with (out / "timeline.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    assert list(rows[0])[-len(COLUMNS):] == list(COLUMNS)
    # each stage reached where the kinetics' own columns say, in order, and kept
    touch = _reached(rows, STAGES["set_to_touch"], -math.inf)
    tack = _reached(rows, STAGES["tack_free"], touch)
    assert touch is not None and tack is not None and 10.0 < touch < tack < 65.0, (touch, tack)
    seen = []
    for row in rows:
        t = float(row["time_s"])
        stage = row["kinetics_stage"]
        expected = "tack_free" if t >= tack + DWELL_S else "set_to_touch" if t >= touch + DWELL_S else "none"
        assert stage == expected, (t, stage, expected)
        if stage != "none":
            assert float(row["kinetics_stage_at_s"]) == {"set_to_touch": touch, "tack_free": tack}[stage]
            assert row["kinetics_next_stage"] == ("tack_free" if stage == "set_to_touch" else "none")
        else:
            assert math.isnan(float(row["kinetics_stage_at_s"])) and row["kinetics_next_stage"] == "set_to_touch"
        if not seen or seen[-1] != stage:
            seen.append(stage)
    assert seen == ["none", "set_to_touch", "tack_free"]
    # the time to tack-free from the rate's trend, midway between the stages: within a factor 2 of
    # the time it took (the film's rate falls about exponentially between them)
    midway = min(rows, key=lambda row: abs(float(row["time_s"]) - (touch + tack) / 2))
    remaining = float(midway["kinetics_time_to_next_s"])
    actual = tack - float(midway["time_s"])
    assert 0.5 * actual < remaining < 2.0 * actual, (remaining, actual)
    assert math.isnan(float(rows[-1]["kinetics_time_to_next_s"]))  # no next stage once all are reached
    print(f"timeline stages: set_to_touch at {touch:.2f} s, tack_free at {tack:.2f} s; midway "
          f"({float(midway['time_s']):.1f} s) the trend said {remaining:.1f} s to tack_free, it took {actual:.1f} s")


def test_without_stages_or_kinetics_no_stage_columns(tmp_path: Path) -> None:
    scene = tmp_path / "film.toml"
    scene.write_text("[scene]\nsize = 32\nseed = 4\ndt = 0.05\n[activity]\ntau_c = 6.0\n"
                     "[detector]\nn_max = 1000.0\nbits = 8\n")
    out = tmp_path / "out"
    assert main(["analyze", str(scene), "--frames", "120", "--timeline", str(out), "--window", "50",
                 "--kinetics", "--kinetics-longest-s", "5", "--no-progress"]) == 0
    header = (out / "timeline.csv").read_text().splitlines()[0].split(",")
    assert "kinetics_tau_s" in header and not set(COLUMNS) & set(header)
