"""The loop closed through the measurement core: ``edgedsm tune`` on a reference run of a surface
that dries fast and of one that dries slowly (the simulator's ``[activity.drying]``), then the
daemon's core (:class:`edgedsm.measurement.Core`, judged at the daemon's cadences: states twice a
second, the noise patches every stats interval) configured from the snippet, on a draw of the
surface it had not seen, shows every state in order: warming_up -> wet -> drying -> dry."""

from __future__ import annotations

import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from edgedsm.cli import main
from edgedsm.config import DaemonConfig
from edgedsm.measurement import Core
from edgedsm.sim import Simulator, load_scene
from edgedsm.validation import validate

REPO = Path(__file__).resolve().parents[3]
DEMO = (REPO / "config" / "scenes" / "drying_demo.toml").read_text().replace("size = 128", "size = 48")
CONFIG = """[camera]
uri = "sim:scene.toml"

[estimator]
window = 100
lag = 5

[[regions]]
name = "plate"
shape = "rect"
x = 4
y = 4
width = 40
height = 40
wet_above = 0.3
dry_below = 0.1
min_dwell_s = 3
"""
DT = 0.05  # the demo scene's frame interval (s)
STATES_EVERY, STATS_EVERY = 0.5, 5.0  # the daemon's cadences (s)
#: (drying start, duration in frames, frames of the run, wet mark, dry mark): τc ×100 over 10 s and 40 s
SPEEDS = {"fast": (200, 200, 800, 10.0, 22.0), "slow": (200, 800, 1300, 10.0, 50.0)}


def _scene(folder: Path, speed: str, seed: int) -> Path:
    start, duration, _, _, _ = SPEEDS[speed]
    text = DEMO.replace("seed = 11", f"seed = {seed}").replace(
        "start = 200\nduration = 800", f"start = {start}\nduration = {duration}")
    assert f"duration = {duration}" in text
    path = folder / f"{speed}-{seed}.toml"
    path.write_text(text)
    return path


def _daemon_states(config: DaemonConfig, scene: Path, frames: int) -> list[tuple[float, str, str]]:
    """The transitions of the daemon's core on the scene's frames, at the daemon's cadences."""
    shape = (48, 48)
    masks = {r.name: r.mask(shape, config.base_dir) for r in config.regions}
    core = Core(config, masks, patch=config.estimator.noise_patch, dt=DT)
    moves, assessed = [], -math.inf
    for index, frame in enumerate(Simulator(load_scene(scene)).frames(frames)):
        core.push(frame, 8)
        now = index * DT
        if not core.ready or round(now / DT) % round(STATES_EVERY / DT):
            continue
        assess = now - assessed >= STATS_EVERY - 1e-9
        assessed = now if assess else assessed
        moves += [(now, str(t.from_state), str(t.to_state)) for t in core.read(now, assess=assess).transitions]
    return moves


@pytest.mark.parametrize("speed", ["fast", "slow"])
def test_tune_then_the_daemons_core_on_an_unseen_draw_goes_wet_drying_dry(speed, tmp_path, capsys):
    _, _, frames, wet_until, dry_from = SPEEDS[speed]
    reference = _scene(tmp_path, speed, seed=11)
    (tmp_path / "daemon.toml").write_text(CONFIG.replace("scene.toml", reference.name))
    snippet = tmp_path / "snippet.toml"
    assert main(["tune", str(reference), "-c", str(tmp_path / "daemon.toml"), "--frames", str(frames),
                 "--wet-until", str(wet_until), "--dry-from", str(dry_from), "--windows", "100", "--lags", "5,10",
                 "--estimators", "s1,s2,s3,tau_c,contrast", "-o", str(snippet), "--json", "--no-progress"]) == 0
    summary = json.loads(capsys.readouterr().out)
    # what is proposed showed every state on the reference run; what skipped one is marked, not proposed
    assert summary["recommended"]["skips"] == []
    assert all(c["skips"] == [] or c["label"] != summary["recommended"]["label"] for c in summary["candidates"])
    proposed = tomllib.loads(snippet.read_text())
    unseen = _scene(tmp_path, speed, seed=29)
    config = validate(DaemonConfig, {"camera": {"uri": f"sim:{unseen}"}, "estimator": proposed["estimator"],
                                     "regions": proposed["regions"]}, "<snippet>")
    moves = _daemon_states(config, unseen, frames)
    path = [(a, b) for _, a, b in moves]
    assert path == [("warming_up", "wet"), ("wet", "drying"), ("drying", "dry")], (summary["reason"], moves)
    # the drying state lasted at least the dwell the region asks of a new state
    times = {b: t for t, _, b in moves}
    assert times["dry"] - times["drying"] >= proposed["regions"][0]["min_dwell_s"]
    assert np.isfinite(times["dry"]) and times["dry"] > wet_until
