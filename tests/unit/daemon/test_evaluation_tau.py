"""τc through the daemon's pipeline and evaluation: region τc in seconds with its status in the
stats, the drying states judged on τc thresholds, the τc map in seconds; off by default."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edgedsm.config import DaemonConfig
from edgedsm.daemon.tau import FrameInterval, engine_estimators
from edgedsm.devices.camera import SimulatedCamera
from edgedsm.frames import Frame
from edgedsm.publish.prometheus import _stats_families
from edgedsm.publish.sink import RecordingSink
from edgedsm.publish.sparkplug.metrics import Reading, declared_readings, stats_readings
from edgedsm.publish.sparkplug.payload import DataType
from edgedsm.sim import load_scene
from edgedsm.validation import validate
from tests.unit.daemon.test_pipeline import hold_back, make_pipeline

DT = 0.05  # the drying demo scene's frame interval


def _config(repo, estimator: dict, regions: list[dict]) -> DaemonConfig:
    data = {"camera": {"uri": f"sim:{repo / 'config' / 'scenes' / 'drying_demo.toml'}"},
            "acquisition": {"dark_frames": 0}, "estimator": {"window": 100, "lag": 5, **estimator}, "regions": regions}
    return validate(DaemonConfig, data, "<tau>")


def _run(config: DaemonConfig, repo, frames: int) -> tuple[RecordingSink, object]:
    scene = load_scene(repo / "config" / "scenes" / "drying_demo.toml")
    scene.scene.size = 64
    camera = SimulatedCamera(scene, time_scale=0)  # as fast as it goes: the host's fps is not Δt
    sink = RecordingSink()
    pipeline = make_pipeline(config, camera, None, sink, dt=DT)
    hold_back(camera, pipeline)
    pipeline.run(lambda: False, max_frames=frames)
    return sink, pipeline


def test_states_judged_on_tau_seconds_and_tau_published(repo):
    config = _config(repo, {"activity": "tau_c", "max_lag": 20},
                     [{"name": "plate", "wet_below_s": 0.2, "dry_above_s": 0.5, "min_dwell_s": 3}])
    sink, pipeline = _run(config, repo, 1300)
    assert pipeline.counters["dropped_queue"] == 0
    moves = [(a.from_state, a.to_state) for a in sink.alerts]
    assert moves == [("warming_up", "wet"), ("wet", "drying"), ("drying", "dry")], sink.alerts
    assert "τc" in sink.alerts[1].reason and sink.alerts[1].activity > 0.2  # left wet above wet_below_s
    ready = [s for s in sink.stats if s.ready]
    assert ready and all(s.frame_interval_s == pytest.approx(DT) for s in ready)  # from the frames' timestamps
    before_drying = [s for s in ready if s.frames <= 200]  # the scene dries from frame 200 on
    assert before_drying, [s.frames for s in ready]
    first = before_drying[0].tau_c["plate"]
    # the scene starts at τc = 3 Δt = 0.15 s (docs/tau_c.md: the region fit is within 10 % at N = 33 τc)
    assert first.status == "measured" and first.tau_c_s == pytest.approx(0.15, rel=0.1), before_drying[0]
    last = ready[-1].tau_c["plate"]
    assert last.status == "above" and last.tau_c_s == pytest.approx(20 * DT)  # τc = 300 Δt > K·Δt: the bound
    assert all(math.isfinite(s.tau_c["plate"].tau_c_s) for s in ready)
    wire = ready[-1].to_json()["tau_c"]["plate"]
    assert wire == {"tau_c_s": pytest.approx(1.0), "status": "above"}
    report = sink.states[-1]
    region = report.regions["plate"]
    assert report.estimator == "tau_c" and region.state == "dry" and region.estimator == "tau_c"
    assert region.activity == pytest.approx(1.0) and region.tau_c_status == "above"
    tau_maps = [m for m in sink.maps if m.name == "tau_c"]
    assert tau_maps and {m.name for m in sink.maps} == {"s1", "s2", "s3", "tau_c"}
    values = tau_maps[-1].values
    assert tau_maps[-1].meta()["unit"] == "s" and tau_maps[-1].meta()["frame_interval_s"] == pytest.approx(DT)
    assert np.isfinite(values).all() and values.max() <= 20 * DT + 1e-12 and values.min() >= 0
    # the sinks that enumerate metrics carry it
    readings = stats_readings(ready[-1])
    assert readings["regions/plate/tau_c_s"].value == pytest.approx(1.0)
    assert readings["regions/plate/tau_c_s"].unit == "s" and readings["regions/plate/tau_c_status"].value == "above"
    assert "regions/plate/tau_c_s" in declared_readings(["plate"], ("s1", "s2", "s3", "tau_c"))
    families = {family.name: family for family in _stats_families(ready[-1])}
    assert families["edgedsm_region_tau_c_seconds"].samples[0].value == pytest.approx(1.0)
    status = {s.labels["status"]: s.value for s in families["edgedsm_region_tau_c_status"].samples}
    assert status == {"measured": 0.0, "above": 1.0, "below": 0.0, "no_signal": 0.0}
    # and each region's signal quality (estimator.noise_floor, on by default), as the stats carry it
    signal = ready[-1].signal["plate"]
    assert readings["regions/plate/signal"].value == signal.signal and signal.signal in ("ok", "low")
    assert readings["regions/plate/mean_intensity"] == Reading(DataType.DOUBLE, signal.mean, "grey levels")
    assert readings["regions/plate/above_noise"].value == signal.above_noise
    assert "regions/plate/signal" in declared_readings(["plate"], ("s1", "s2", "s3", "tau_c"))
    verdict = {s.labels["signal"]: s.value for s in families["edgedsm_region_signal"].samples}
    assert verdict == {name: float(name == signal.signal) for name in ("ok", "low", "dark", "saturated", "not_speckle")}
    assert families["edgedsm_region_mean_intensity"].samples[0].value == signal.mean > 0


def test_tau_c_off_by_default_and_a_tau_region_beside_an_s2_one(repo):
    plain = _config(repo, {}, [{"name": "plate", "wet_above": 0.24, "dry_below": 0.10}])
    sink, _ = _run(plain, repo, 160)
    assert engine_estimators(plain) == ("s1", "s2", "s3")  # no τc sums: the push costs S1+S2+S3 only
    assert all(s.tau_c == {} and s.frame_interval_s is None for s in sink.stats)
    assert "tau_c" not in {m.name for m in sink.maps}

    mixed = _config(repo, {"max_lag": 20, "tau_c_map": False},
                    [{"name": "plate", "wet_above": 0.24, "dry_below": 0.10},
                     {"name": "corner", "shape": "rect", "x": 0, "y": 0, "width": 32, "height": 32,
                      "wet_below_s": 0.2, "dry_above_s": 0.5}])
    sink, _pipeline = _run(mixed, repo, 160)
    assert engine_estimators(mixed) == ("s1", "s2", "s3", "tau_c")
    last = [s for s in sink.stats if s.ready][-1]
    assert set(last.tau_c) == {"plate", "corner"} and last.estimator == "s2"
    report = sink.states[-1].regions
    assert report["plate"].estimator is None and report["corner"].estimator == "tau_c"
    assert report["corner"].activity == pytest.approx(last.tau_c["corner"].tau_c_s, rel=0.3)
    assert report["corner"].state == "wet" and report["plate"].state == "wet"
    assert "tau_c" not in {m.name for m in sink.maps}  # tau_c_map = false


def test_frame_interval_prefers_the_configured_one_then_the_frames_timestamps():
    pixels = np.zeros((2, 2), np.uint8)
    configured = FrameInterval(0.04)
    configured.saw(Frame(pixels, 0, 0, 8))
    assert configured.seconds(fps=100.0) == 0.04
    stamped = FrameInterval(None)
    assert stamped.seconds() is None and stamped.seconds(fps=20.0) == pytest.approx(0.05)
    for seq in (0, 1, 2, 4, 5, 6):  # frame 3 lost upstream: its gap is two intervals, not one long one
        stamped.saw(Frame(pixels, seq, seq * 25_000_000, 8))
    assert stamped.seconds(fps=1000.0) == pytest.approx(0.025)


def test_thresholds_beyond_the_measured_range_raise_one_warning_per_region(repo):
    # no camera.frame_interval_s: Δt (0.05 s) is known only once frames flow; then dry_above_s =
    # 2 s is beyond K·Δt = 20 x 0.05 s = 1 s and can never be reached: a warning alert, once
    config = _config(repo, {"max_lag": 20},
                     [{"name": "plate", "wet_below_s": 0.2, "dry_above_s": 2.0},
                      {"name": "fine", "shape": "rect", "x": 0, "y": 0, "width": 16, "height": 16,
                       "wet_below_s": 0.2, "dry_above_s": 0.5}])
    sink, _ = _run(config, repo, 400)
    warnings = [a for a in sink.alerts if a.kind == "warning"]
    assert [a.region for a in warnings] == ["plate"], sink.alerts
    assert "dry_above_s" in warnings[0].reason and "0.05 s" in warnings[0].reason and "1 s" in warnings[0].reason
