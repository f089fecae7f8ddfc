"""The measurement core (edgedsm.measurement): one object from frames to per-region values, floors,
judged activity, signal and states, the same through each of its entries; and its place below the
daemon (no upward import from it, nor from the numerics and tuning that use it)."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from edgedsm.config import DaemonConfig
from edgedsm.drying import DryingMonitor, Thresholds
from edgedsm.measurement import REGION_VIEW, Core, judge_window, view_of
from edgedsm.measurement.core import step_states
from edgedsm.sim import Simulator, load_scene
from edgedsm.validation import validate

REPO = Path(__file__).resolve().parents[3]
SCENE = (REPO / "config" / "scenes" / "drying_demo.toml").read_text().replace("size = 128", "size = 40")


def _config(**estimator: object) -> DaemonConfig:
    return validate(DaemonConfig, {"camera": {"uri": "sim:default", "noise": {"gain": 0.25}},
                                   "estimator": {"window": 60, "lag": 3, "activity": "s2", **estimator},
                                   "regions": [{"name": "plate", "shape": "rect", "x": 4, "y": 4, "width": 32,
                                                "height": 32, "wet_above": 0.3, "dry_below": 0.1}]}, "<core>")


@pytest.fixture(scope="module")
def frames(tmp_path_factory) -> np.ndarray:
    scene = tmp_path_factory.mktemp("core") / "scene.toml"
    scene.write_text(SCENE)
    return np.stack(list(Simulator(load_scene(scene)).frames(60)))


def test_a_cores_reading_is_the_window_judged_once_with_the_same_frames(frames):
    config = _config()
    mask = config.regions[0].mask(frames.shape[1:], config.base_dir)
    core = Core(config, {"plate": mask}, floored=("s1", "s3"))
    for frame in frames:
        core.push(frame, 8)
    evaluation = core.read(3.0)
    reading = evaluation.readings["plate"]
    # the first state is the judged activity (above the floor) against wet_above 0.3, dry_below 0.1
    first = "wet" if reading.activity >= 0.3 else "dry" if reading.activity <= 0.1 else "drying"
    assert reading.view == REGION_VIEW and reading.estimator == "s2" and reading.state == first
    assert [(str(t.from_state), str(t.to_state)) for t in evaluation.transitions] == [("warming_up", first)]
    assert reading.plain > reading.activity > 0  # S2 above its floor
    assert set(reading.above) == set(reading.floors) == {"s1", "s2", "s3"}
    assert reading.plain == reading.values["s2"] and reading.activity == pytest.approx(reading.above["s2"])
    assert 0 < reading.floors["s2"] < reading.plain and reading.signal.signal == "ok"
    # the same window through the entry analyze's map takes: the same floor, value above it and signal
    once, above, _ = judge_window(config, frames, reading.values, bits=8, mask=mask, region="plate")
    assert once.floors["s2"] == pytest.approx(reading.floors["s2"], rel=1e-12)
    assert once.activity == pytest.approx(reading.activity, rel=1e-12) and above.value == pytest.approx(
        reading.activity, rel=1e-12)
    assert once.signal == reading.signal
    # the daemon's view: a patch at the region's centre, named, with its own floor
    patched = Core(config, {"plate": mask}, patch=16)
    for frame in frames:
        patched.push(frame, 8)
    seen = patched.read(3.0).readings["plate"]
    assert seen.view == view_of(16) == "patch 16x16 px at the region's centre" and seen.values == reading.values
    assert seen.floors["s2"] != reading.floors["s2"]


def test_without_the_noise_floor_the_plain_activity_is_judged_and_no_signal_given(frames):
    config = _config(noise_floor=False)
    core = Core(config, {"plate": config.regions[0].mask(frames.shape[1:], config.base_dir)})
    for frame in frames:
        core.push(frame, 8)
    reading = core.read(3.0).readings["plate"]
    assert reading.activity == reading.plain == reading.values["s2"] and reading.signal is None
    assert reading.above == {} and core.patches is None


def test_a_region_without_a_judged_value_keeps_its_state():
    monitor = DryingMonitor({"a": Thresholds(0.6, 0.3, 0.05, 0.0)})
    assert [str(t.to_state) for t in step_states(monitor, 0.0, {"a": 0.9})] == ["wet"]
    assert step_states(monitor, 1.0, {"a": None}) == [] and monitor.regions["a"].state == "wet"
    assert [str(t.to_state) for t in step_states(monitor, 2.0, {"a": 0.1})] == ["dry"]


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text())
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module:
            out.add(node.module)
        elif isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names)
    return out


@pytest.mark.parametrize("below", ["measurement", "tuning", "timeline.py", "analysis.py", "drying.py"])
def test_the_core_and_what_uses_it_below_the_daemon_import_nothing_above_them(below):
    root = REPO / "edgedsm" / below
    files = sorted(root.rglob("*.py")) if root.is_dir() else [root]
    above = ("edgedsm.daemon", "edgedsm.commands", "edgedsm.publish", "edgedsm.dashboard")
    upward = {f"{path.relative_to(REPO)}: {name}" for path in files for name in _imports(path)
              if name.startswith(above)}
    assert files and not upward
