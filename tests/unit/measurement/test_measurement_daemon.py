"""The daemon's evaluator and the measurement core are one computation: the simulated darkening
film through the daemon's pipeline and, frame for frame, through :class:`edgedsm.measurement.Core`
(the daemon's patch, assessed at the frames of the daemon's stats) give the same noise floor, value
above it, signal and state at every stats message."""

from __future__ import annotations

from pathlib import Path

import pytest

from edgedsm.config import DaemonConfig
from edgedsm.devices.camera import SimulatedCamera
from edgedsm.measurement import Core
from edgedsm.publish.sink import RecordingSink
from edgedsm.sim import Simulator, load_scene
from edgedsm.validation import validate
from tests.unit.daemon.test_pipeline import hold_back, make_pipeline

SCENE = (Path(__file__).resolve().parents[3] / "config" / "scenes" / "darkening_film.toml").read_text().replace(
    "size = 128", "size = 48")
FRAMES = 900


def test_the_daemon_and_the_core_judge_the_same_frames_alike(tmp_path):
    scene = tmp_path / "film.toml"
    scene.write_text(SCENE)
    config = validate(DaemonConfig, {"camera": {"uri": f"sim:{scene}"}, "acquisition": {"dark_frames": 0},
                                     "estimator": {"window": 100, "lag": 5, "activity": "s2", "noise_patch": 32},
                                     "regions": [{"name": "film", "wet_above": 0.30, "dry_below": 0.05,
                                                  "min_dwell_s": 2.0}]}, "<agreement>")
    sink = RecordingSink()
    camera = SimulatedCamera(load_scene(scene), time_scale=0)
    pipeline = make_pipeline(config, camera, None, sink, dt=0.05)
    hold_back(camera, pipeline)
    pipeline.run(lambda: False, max_frames=FRAMES)
    judged = [stats for stats in sink.stats if stats.ready and "film" in stats.signal]
    assert len(judged) >= 5
    at = {stats.frames: stats for stats in judged}
    core = Core(config, {"film": config.regions[0].mask((48, 48), config.base_dir)}, patch=32, dt=0.05)
    compared = 0
    for index, frame in enumerate(Simulator(load_scene(scene)).frames(FRAMES)):
        core.push(frame, 8)
        stats = at.get(index + 1)
        if stats is None:
            continue
        reading = core.read(index * 0.05).readings["film"]
        daemon = stats.signal["film"]
        assert reading.values["s2"] == pytest.approx(stats.regions["film"]["s2"].mean, rel=1e-9)
        assert reading.signal.signal == daemon.signal and reading.signal.noise_model == daemon.noise_model
        if daemon.noise_floor is None:
            assert "s2" not in reading.floors
        else:
            assert reading.floors["s2"] == pytest.approx(daemon.noise_floor, rel=1e-9)
            assert reading.above["s2"] == pytest.approx(daemon.above_noise, rel=1e-9, abs=1e-12)
        compared += 1
    assert compared == len(judged)
    assert any(stats.signal["film"].noise_floor is not None for stats in judged)  # a floor was compared


def test_the_daemon_and_the_core_give_the_same_region_tau(tmp_path):
    """τc in one place: the daemon's evaluator (TauRegions on the pipeline's snapshots, Δt from the
    frames' timestamps) and the Core (its engine's snapshot, Δt given) publish the same τc in
    seconds and status at every stats message."""
    scene = tmp_path / "film.toml"
    scene.write_text(SCENE)
    config = validate(DaemonConfig, {"camera": {"uri": f"sim:{scene}"}, "acquisition": {"dark_frames": 0},
                                     "estimator": {"window": 100, "lag": 5, "activity": "s2", "tau_c": True,
                                                   "max_lag": 20},
                                     "regions": [{"name": "film", "wet_above": 0.30, "dry_below": 0.05}]},
                      "<agreement>")
    sink = RecordingSink()
    camera = SimulatedCamera(load_scene(scene), time_scale=0)
    pipeline = make_pipeline(config, camera, None, sink, dt=0.05)
    hold_back(camera, pipeline)
    frames = 400
    pipeline.run(lambda: False, max_frames=frames)
    at = {stats.frames: stats for stats in sink.stats if stats.ready and "film" in stats.tau_c}
    assert len(at) >= 3
    interval_s = 1.0  # the scene gives no frame interval: the simulator's frames are 1 s apart
    core = Core(config, {"film": config.regions[0].mask((48, 48), config.base_dir)}, patch=32, dt=interval_s)
    compared, statuses = 0, set()
    for index, frame in enumerate(Simulator(load_scene(scene)).frames(frames)):
        core.push(frame, 8)
        stats = at.get(index + 1)
        if stats is None:
            continue
        reading = core.read(index * 0.05).readings["film"]
        daemon = stats.tau_c["film"]
        assert stats.frame_interval_s == pytest.approx(interval_s, rel=1e-9)  # from the frames' timestamps
        assert reading.tau_c_status == daemon.status
        assert reading.tau_c_s == pytest.approx(daemon.tau_c_s, rel=1e-12)  # bit for bit when both Δt are 1 s
        statuses.add(daemon.status)
        compared += 1
    assert compared == len(at) and "measured" in statuses
