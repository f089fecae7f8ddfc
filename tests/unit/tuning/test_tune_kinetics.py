"""tune scores the kinetics (issue 37, part 3; docs/commissioning.md): on a simulated drying run
(the demo plate at 48², τc 3 -> 300 frames) the kinetics is one candidate, judged as τc is (its
rate; thresholds in seconds), replayed through the daemon's state machine, its cost measured; the
snippet that chooses it enables ``[kinetics]`` and is a config the daemon accepts, and the daemon's
core configured from it goes wet -> drying -> dry on a draw it had not seen. A drying too fast for
the dwell is marked ``skips``; two recordings joined do not allow it (not scored, with the reason)."""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from edgedsm.cli import main
from edgedsm.config import DaemonConfig, load_config
from edgedsm.measurement import Core
from edgedsm.sim import Simulator, load_scene
from edgedsm.tuning.series import DEFAULT_CANDIDATES, KINETICS
from edgedsm.tuning.session import Run, settings_for, tune
from edgedsm.validation import validate

REPO = Path(__file__).resolve().parents[3]
DEMO = (REPO / "config" / "scenes" / "drying_demo.toml").read_text().replace("size = 128", "size = 48")
CONFIG = """[camera]
uri = "sim:scene.toml"
frame_interval_s = 0.05

[device]
state_dir = "state"

[estimator]
window = 100
lag = 5

[kinetics]
longest_age_s = 120.0
[[kinetics.stages]]
name = "tack_free"
rate_below_hz = 0.5

[[regions]]
name = "plate"
shape = "rect"
x = 4
y = 4
width = 40
height = 40
wet_above = 0.3
dry_below = 0.1
min_dwell_s = DWELL
"""
DT = 0.05
FRAMES, WET_UNTIL, DRY_FROM = 1300, 10.0, 50.0  # τc ×100 between 10 s and 50 s


def _write(folder: Path, seed: int = 11, duration: int = 800, dwell: float = 3.0) -> tuple[Path, Path]:
    scene = folder / f"scene-{seed}-{duration}.toml"
    scene.write_text(DEMO.replace("seed = 11", f"seed = {seed}").replace("duration = 800", f"duration = {duration}"))
    config = folder / "daemon.toml"
    config.write_text(CONFIG.replace("scene.toml", scene.name).replace("DWELL", str(dwell)))
    return scene, config


def _tune(scene: Path, config: Path, capsys, *extra: str) -> dict:
    assert main(["tune", str(scene), "-c", str(config), "--frames", str(FRAMES), "--wet-until", str(WET_UNTIL),
                 "--dry-from", str(DRY_FROM), "--windows", "100", "--lags", "5", "--json", "--no-progress",
                 *extra]) == 0
    return json.loads(capsys.readouterr().out)


def test_the_kinetics_is_scored_like_tau_c_and_its_snippet_dries_an_unseen_draw(tmp_path, capsys) -> None:
    assert KINETICS in DEFAULT_CANDIDATES
    scene, config = _write(tmp_path)
    summary = _tune(scene, config, capsys, "--estimators", "s2,tau_c,kinetics", "-o", str(tmp_path / "s.toml"))
    by_label = {c["label"]: c for c in summary["candidates"]}
    kinetics = by_label["τ (kinetics)"]  # one candidate: no window setting
    assert [c["estimator"] for c in summary["candidates"]].count("kinetics") == 1
    assert kinetics["sound"] and kinetics["auc"] > 0.99 and kinetics["skips"] == []
    thresholds = kinetics["regions"]["plate"]["thresholds"]
    # in seconds, small = wet, as τc's; the dry one below the oldest reference (the config's 120 s
    # at 4 per octave: 100.9 s) with its hysteresis, so that the daemon can call dry
    assert set(thresholds) == {"wet_below_s", "dry_above_s", "hysteresis", "min_dwell_s"}
    assert 0.15 < thresholds["wet_below_s"] < thresholds["dry_above_s"] < 15.0
    assert thresholds["dry_above_s"] * (1 + thresholds["hysteresis"]) < 120.0 / 2 ** 0.25
    # replayed through the daemon's state machine: wet -> drying -> dry, dry after the wet mark
    moves = [(a, b) for _, a, b in kinetics["regions"]["plate"]["transitions"]]
    assert moves[-2:] == [("wet", "drying"), ("drying", "dry")]
    assert WET_UNTIL - DRY_FROM < kinetics["delay_s"] < 15.0
    # its cost per frame measured: the push of 1,600 pixels and a read every 10 frames, more than
    # S2's engine push of the same frames' 1,600 pixels would be absurd beyond 100×, and never 0
    s2 = by_label["S2, N=100 m=5 sliding"]
    assert 0 < kinetics["cost_ms_per_frame"] < 100 * s2["cost_ms_per_frame"] + 1.0
    # the snippet choosing it (asked for alone) enables [kinetics] and the daemon accepts it
    summary = _tune(scene, config, capsys, "--estimators", "kinetics", "-o", str(tmp_path / "k.toml"))
    assert summary["recommended"]["estimator"] == "kinetics" and summary["not_scored"] == []
    proposed = tomllib.loads((tmp_path / "k.toml").read_text())
    assert proposed["estimator"]["activity"] == "kinetics"
    assert proposed["kinetics"]["enabled"] is True and proposed["kinetics"]["longest_age_s"] == 120.0
    assert proposed["kinetics"]["stages"] == [{"name": "tack_free", "rate_below_hz": 0.5}]
    assert proposed["regions"][0]["dry_above_s"] == summary["recommended"]["regions"]["plate"]["thresholds"][
        "dry_above_s"]
    unseen, _ = _write(tmp_path, seed=29)
    daemon = validate(DaemonConfig, {"camera": {"uri": f"sim:{unseen}", "frame_interval_s": DT},
                                     "estimator": proposed["estimator"], "kinetics": proposed["kinetics"],
                                     "regions": proposed["regions"]}, "<snippet>")
    core = Core(daemon, {"plate": daemon.regions[0].mask((48, 48), daemon.base_dir)}, dt=DT)
    path = []
    for index, frame in enumerate(Simulator(load_scene(unseen)).frames(FRAMES)):
        core.push(frame, 8)
        now = index * DT
        if core.ready and index % 10 == 0:  # the daemon's states cadence, 0.5 s
            path += [(now, str(t.from_state), str(t.to_state)) for t in core.read(now).transitions]
    assert [(a, b) for _, a, b in path] == [("warming_up", "wet"), ("wet", "drying"), ("drying", "dry")], path
    assert path[-1][0] > WET_UNTIL


def test_a_drying_faster_than_the_dwell_is_marked_skips_and_not_proposed(tmp_path, capsys) -> None:
    # τc ×100 within 50 frames (2.5 s), a dwell of 8 s: the kinetics crosses its drying band in it
    scene, config = _write(tmp_path, duration=50, dwell=8.0)
    assert main(["tune", str(scene), "-c", str(config), "--frames", "900", "--wet-until", "10",
                 "--dry-from", "30", "--windows", "100", "--lags", "5", "--estimators", "kinetics,s2", "--json",
                 "--no-progress"]) in (0, 65)
    summary = json.loads(capsys.readouterr().out)
    kinetics = next(c for c in summary["candidates"] if c["estimator"] == "kinetics")
    assert kinetics["skips"] == ["drying"], kinetics["regions"]["plate"]["transitions"]
    assert (summary["recommended"] or {}).get("estimator") != "kinetics"


def test_two_recordings_joined_do_not_allow_the_kinetics(tmp_path) -> None:
    scene, path = _write(tmp_path)
    config = load_config(path)
    frames = np.stack(list(Simulator(load_scene(scene)).frames(FRAMES)))
    run = Run(lambda: iter(frames), FRAMES, 8, DT, None, WET_UNTIL, DRY_FROM, "wet + dry", joined=True)
    masks = {"plate": config.regions[0].mask((48, 48), config.base_dir)}
    result = tune(run, config, masks, 60.0, settings_for(run, (100,), (5,)), estimators=("s2", KINETICS))
    assert [c.estimator for c, _ in result.excluded] == [KINETICS]
    assert "two recordings joined" in result.excluded[0][1]
    assert all(o.candidate.estimator != KINETICS for o in result.outcomes)
    # frame times off one interval (a burst) do not allow it either; a steady clock does
    times = np.arange(FRAMES) * DT + np.random.default_rng(1).uniform(-0.2, 0.2, FRAMES) * DT  # a camera's jitter
    assert Run(lambda: iter(frames), FRAMES, 8, DT, times, WET_UNTIL, DRY_FROM, "run").kinetics_problem() is None
    times[600:] += DT  # one frame dropped
    assert "one interval" in Run(lambda: iter(frames), FRAMES, 8, DT, times, WET_UNTIL, DRY_FROM,
                                 "run").kinetics_problem()
    assert math.isfinite(result.outcomes[0].cost_s)


@pytest.fixture(autouse=True)
def _in_tmp(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)  # device.state_dir = "state": tune keeps its last report there
