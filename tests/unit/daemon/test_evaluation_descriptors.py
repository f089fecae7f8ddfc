"""The field's descriptors through the daemon (issue 24): the drying states judged on Fujii and on GD
(above their noise floors; GD in both window modes), on the temporal contrast (above its floor:
the signal's contrast) and on the band ratio (no floor), their region statistics, maps and metrics
in every sink, and the config's rules for them (Fujii runs the engine at q = 0, GD and the band
ratio need a window mode, the band split lies below Nyquist)."""

from __future__ import annotations

import json
import math

import pytest

from edgedsm.cli import main
from edgedsm.config import DaemonConfig, load_config
from edgedsm.daemon.engine_budget import engine_bytes_per_pixel
from edgedsm.daemon.tau import engine_estimators
from edgedsm.dashboard.plant import Plant
from edgedsm.errors import ConfigError
from edgedsm.estimators import SlidingWindow
from edgedsm.publish.ha_discovery import Discovery
from edgedsm.publish.mapcodec import encode_map
from edgedsm.publish.prometheus import _stats_families
from edgedsm.publish.sparkplug.metrics import declared_readings, map_reading, stats_readings
from edgedsm.publish.topics import Topics
from edgedsm.validation import validate
from tests.unit.daemon.test_evaluation_tau import _config, _run

PLATE = {"name": "plate", "min_dwell_s": 3}


def _moves(sink) -> list[tuple[str, str]]:
    return [(a.from_state, a.to_state) for a in sink.alerts if a.kind != "warning"]


@pytest.mark.parametrize(("activity", "mode", "thresholds", "wet", "dry", "top"), [
    # the demo scene at 64²: Fujii ~58 while wet, ~13 (4 above its floor of ~9) once dry
    ("fujii", "sliding", (40.0, 8.0), (50, 70), (10, 16), 200.0),
    # GD ~34.5 grey levels while wet, ~11.2 (7.4 above its floor of ~3.8) once dry
    ("gd", "sliding", (25.0, 9.0), (30, 40), (9, 14), 255.0),
    ("gd", "tumbling", (25.0, 9.0), (30, 40), (9, 14), 255.0),  # the maps of each completed block
])
def test_drying_judged_on_a_descriptor_above_its_noise_floor(repo, activity, mode, thresholds, wet, dry, top):
    config = _config(repo, {"activity": activity, "mode": mode},
                     [{**PLATE, "wet_above": thresholds[0], "dry_below": thresholds[1]}])
    if activity == "fujii":
        assert config.estimator.engine_q == 0.0 and config.estimator.q == 1.0  # q left out: the engine runs at 0
    assert engine_estimators(config) == ("s1", "s2", "s3", activity)
    sink, pipeline = _run(config, repo, 1300)
    assert pipeline.counters["dropped_queue"] == 0
    assert _moves(sink) == [("warming_up", "wet"), ("wet", "drying"), ("drying", "dry")], sink.alerts
    ready = [s for s in sink.stats if s.ready]
    assert all(s.estimator == activity and set(s.regions["plate"]) == {"s1", "s2", "s3", activity} for s in ready)
    for stats in ready if activity == "fujii" else ():  # 200·S2 of the same q = 0 sums, region by region
        plate = stats.regions["plate"]
        assert plate["fujii"].mean == pytest.approx(200 * plate["s2"].mean, rel=1e-12)
        assert plate["fujii"].p95 == pytest.approx(200 * plate["s2"].p95, rel=1e-12)
    first, last = ready[0].regions["plate"][activity], ready[-1].regions["plate"][activity]
    assert wet[0] < first.mean < wet[1] and dry[0] < last.mean < dry[1], (first, last)
    assert 0 < first.p05 <= first.median <= first.p95 and first.std > 0  # the region's spread, not only its mean
    signal = ready[-1].signal["plate"]
    assert signal.noise_floor is not None and signal.above_noise == pytest.approx(last.mean - signal.noise_floor)
    report = sink.states[-1]
    assert report.estimator == activity and report.regions["plate"].state == "dry"
    assert report.regions["plate"].activity == pytest.approx(signal.above_noise, rel=0.05)
    maps = [m for m in sink.maps if m.name == activity]
    assert maps and {m.name for m in sink.maps} == {"s1", "s2", "s3", activity}
    assert math.isfinite(maps[-1].values.max()) and maps[-1].values.min() >= 0 and maps[-1].values.max() <= top
    # every sink that enumerates metrics carries it
    readings = stats_readings(ready[-1])
    assert readings[f"regions/plate/{activity}/mean"].value == last.mean
    assert f"regions/plate/{activity}/mean" in declared_readings(["plate"], engine_estimators(config))
    families = {family.name: family for family in _stats_families(ready[-1])}
    samples = {s.labels["map"]: s.value for s in families["edgedsm_region_map_mean"].samples}
    assert samples == {name: ready[-1].regions["plate"][name].mean for name in ("s1", "s2", "s3", activity)}
    # `activity`: the judged value, above the floor (the stats' and the state report's number)
    judged = ready[-1].activity["plate"]
    assert judged.estimator == activity and judged.basis == "above_noise" and judged.value < last.mean
    assert [s.value for s in families["edgedsm_region_activity"].samples] == [judged.value]
    entity = Discovery("homeassistant", Topics("edgedsm/test"), "test").map_mean_entity("plate", activity)
    assert f"'{activity}'" in entity.config["value_template"] and entity.config["state_topic"] == "edgedsm/test/stats"
    dashboard = Plant("edgedsm", None, lambda kind, data: None)
    dashboard.handle("edgedsm/cam/stats", ready[-1].to_bytes())
    png, meta = encode_map(maps[-1].values, estimator=activity)
    dashboard.handle(f"edgedsm/cam/map/{activity}/meta", json.dumps(meta).encode())
    dashboard.handle(f"edgedsm/cam/map/{activity}", png)
    (device,) = dashboard.snapshot()
    assert device["stats"]["activity"] == {"plate": judged.value} and device["stats"]["estimator"] == activity
    assert device["stats"]["plain"] == {"plate": last.mean}
    assert device["maps"][activity]["max"] == pytest.approx(float(maps[-1].values.max()), rel=1e-3)


def test_drying_judged_on_the_temporal_contrast_above_its_floor(repo):
    # σ/⟨I⟩ of the demo scene: ~0.65 while wet, ~0.21 once dry; above the noise a little less
    config = _config(repo, {"activity": "contrast"}, [{**PLATE, "wet_above": 0.55, "dry_below": 0.3}])
    assert config.estimator.engine_q == 1.0 and engine_estimators(config) == ("s1", "s2", "s3", "contrast")
    sink, _ = _run(config, repo, 1300)
    assert _moves(sink) == [("warming_up", "wet"), ("wet", "drying"), ("drying", "dry")], sink.alerts
    ready = [s for s in sink.stats if s.ready]
    last = ready[-1].regions["plate"]["contrast"]
    assert 0.6 < ready[0].regions["plate"]["contrast"].mean < 0.7 and 0.15 < last.mean < 0.3
    signal = ready[-1].signal["plate"]
    # the noise adds in quadrature: the signal's contrast is below the plain one, the floor well below both
    assert signal.signal in ("ok", "low") and signal.noise_floor is not None and signal.above_noise is not None
    assert 0.0 < signal.noise_floor < 0.5 * signal.above_noise < 0.5 * last.mean
    assert signal.above_noise > 0.8 * last.mean  # the demo plate's noise is a small share of its fluctuation
    report = sink.states[-1]
    same = [s for s in ready if s.t == report.t]  # the stats evaluated with that report
    assert same and report.regions["plate"].activity == pytest.approx(same[0].signal["plate"].above_noise, rel=1e-9)
    assert report.regions["plate"].activity < same[0].regions["plate"]["contrast"].mean
    assert "contrast" in {m.name for m in sink.maps}


def test_the_config_takes_the_descriptors_and_refuses_fujii_with_a_q(repo):
    inertia = _config(repo, {"activity": "im"}, [{**PLATE, "wet_above": 400.0, "dry_below": 50.0}])
    assert engine_estimators(inertia) == ("s1", "s2", "s3", "im") and inertia.estimator.engine_q == 1.0
    assert map_reading("plate", "im", 120.0)[1].unit == "grey levels²"  # Sparkplug's engineering unit
    assert map_reading("plate", "gd", 30.0)[1].unit == "grey levels"
    assert _config(repo, {"activity": "fujii", "q": 0}, [{**PLATE, "wet_above": 40.0, "dry_below": 8.0}])
    with pytest.raises(ConfigError, match=r"estimator.q: Value error, q = 2.0 with estimator.activity = .fujii."):
        _config(repo, {"activity": "fujii", "q": 2.0}, [{**PLATE, "wet_above": 40.0, "dry_below": 8.0}])
    generalized = _config(repo, {"activity": "gd", "mode": "tumbling"},
                          [{**PLATE, "wet_above": 25.0, "dry_below": 9.0}])
    assert engine_estimators(generalized) == ("s1", "s2", "s3", "gd") and generalized.estimator.engine_q == 1.0


def test_gd_in_the_exponential_mode_is_a_config_error_naming_its_key(tmp_path, capsys):
    path = tmp_path / "gd.toml"
    path.write_text('[camera]\nuri = "sim:default"\n\n[estimator]\nactivity = "gd"\nmode = "exponential"\n\n'
                    '[[regions]]\nname = "plate"\nwet_above = 25.0\ndry_below = 9.0\n')
    with pytest.raises(ConfigError, match=r"gd\.toml"):
        load_config(path)
    assert main(["check-config", str(path)]) == 78
    assert ("estimator: Value error, activity: gd needs mode 'sliding' or 'tumbling', not 'exponential' (its exact "
            "sum reads the window's frames, and the exponential mode keeps none)") in capsys.readouterr().err



def test_drying_judged_on_the_band_ratio(repo):
    # high-band / low-band power at the default split (half the Nyquist frequency), q = 0: the demo
    # plate's ratio ~0.15 while wet (τc = 3 frames), ~0.06 at frame 700 as it slows; no noise floor
    config = _config(repo, {"activity": "band_ratio", "q": 0},
                     [{**PLATE, "wet_above": 0.14, "dry_below": 0.07}])
    assert engine_estimators(config) == ("s1", "s2", "s3", "band_ratio")
    assert config.band_args == {"dt": None, "band_split": None}
    sink, pipeline = _run(config, repo, 720)
    assert pipeline.counters["dropped_queue"] == 0
    assert _moves(sink) == [("warming_up", "wet"), ("wet", "drying"), ("drying", "dry")], sink.alerts
    ready = [s for s in sink.stats if s.ready]
    assert all(s.estimator == "band_ratio" and set(s.regions["plate"]) == {"s1", "s2", "s3", "band_ratio"}
               for s in ready)
    first, last = ready[0].regions["plate"]["band_ratio"], ready[-1].regions["plate"]["band_ratio"]
    assert 0.14 < first.mean < 0.17 and 0.05 < last.mean < 0.07, (first, last)
    assert 0 <= last.p05 <= last.median <= last.p95 and last.std > 0
    signal = ready[-1].signal["plate"]
    assert signal.noise_floor is None and signal.above_noise is None  # none defined (docs/noise.md)
    report = sink.states[-1]
    assert report.estimator == "band_ratio" and report.regions["plate"].state == "dry"
    maps = [m for m in sink.maps if m.name == "band_ratio"]
    assert maps and {m.name for m in sink.maps} == {"s1", "s2", "s3", "band_ratio"}
    values = maps[-1].values
    assert math.isfinite(values.max()) and values.min() >= 0
    readings = stats_readings(ready[-1])
    assert readings["regions/plate/band_ratio/mean"].value == last.mean
    assert "regions/plate/band_ratio/mean" in declared_readings(["plate"], engine_estimators(config))
    families = {family.name: family for family in _stats_families(ready[-1])}
    samples = {s.labels["map"]: s.value for s in families["edgedsm_region_map_mean"].samples}
    assert samples == {name: ready[-1].regions["plate"][name].mean for name in ("s1", "s2", "s3", "band_ratio")}
    # no floor for the band ratio: the judged value is the plain mean itself
    assert ready[-1].activity["plate"].basis == "plain"
    assert [s.value for s in families["edgedsm_region_activity"].samples] == [ready[-1].activity["plate"].value]
    entity = Discovery("homeassistant", Topics("edgedsm/test"), "test").map_mean_entity("plate", "band_ratio")
    assert "'band_ratio'" in entity.config["value_template"]
    dashboard = Plant("edgedsm", None, lambda kind, data: None)
    dashboard.handle("edgedsm/cam/stats", ready[-1].to_bytes())
    png, meta = encode_map(values, estimator="band_ratio")
    dashboard.handle("edgedsm/cam/map/band_ratio/meta", json.dumps(meta).encode())
    dashboard.handle("edgedsm/cam/map/band_ratio", png)
    (device,) = dashboard.snapshot()
    assert device["stats"]["activity"] == {"plate": ready[-1].activity["plate"].value}
    assert device["stats"]["plain"] == {"plate": last.mean} and device["stats"]["estimator"] == "band_ratio"
    assert device["maps"]["band_ratio"]["max"] == pytest.approx(float(values.max()), rel=1e-3)


def test_the_band_ratio_config_rules(repo):
    regions = [{**PLATE, "wet_above": 0.14, "dry_below": 0.07}]

    def config(estimator: dict, camera: dict | None = None) -> DaemonConfig:
        return validate(DaemonConfig, {"camera": {"uri": "sim:x", **(camera or {})},
                                       "estimator": {"activity": "band_ratio", "window": 64, "lag": 1, **estimator},
                                       "regions": regions}, "<bands>")

    split = config({"band_split_hz": 5.0}, {"frame_interval_s": 0.02})
    assert split.band_args == {"dt": 0.02, "band_split": 5.0}
    with pytest.raises(ConfigError, match=r"estimator.band_split_hz: .*Nyquist frequency 25 Hz"):
        config({"band_split_hz": 25.0}, {"frame_interval_s": 0.02})
    with pytest.raises(ConfigError, match=r"estimator.band_split_hz: a split in Hz needs camera.frame_interval_s"):
        config({"band_split_hz": 5.0})
    with pytest.raises(ConfigError, match=r"estimator: .*activity: the frequency bands .* not 'exponential'"):
        config({"mode": "exponential"})
    assert config({"mode": "tumbling"}).estimator.maps == ("s1", "s2", "s3", "band_ratio")


def test_check_config_says_the_band_ratio_has_no_floor(tmp_path, capsys):
    path = tmp_path / "bands.toml"
    path.write_text('[camera]\nuri = "sim:default"\nframe_interval_s = 0.02\n\n[estimator]\nactivity = "band_ratio"\n'
                    'window = 64\nlag = 1\nband_split_hz = 5.0\n\n[[regions]]\nname = "plate"\nwet_above = 0.2\n'
                    'dry_below = 0.1\n')
    assert main(["check-config", str(path)]) == 0
    assert "noise floor: on, band_ratio has none: states judged on it as it is" in capsys.readouterr().out
    path.write_text(path.read_text().replace("band_split_hz = 5.0", "band_split_hz = 25.0"))
    assert main(["check-config", str(path)]) == 78
    assert "estimator.band_split_hz: the band split must lie between 0 and the Nyquist frequency 25 Hz" \
        in capsys.readouterr().err


def test_the_memory_check_counts_the_band_bins():
    # N = 64, default split: 16 bins of 16 B kept, and copied once for the maps; one more float map
    plain = SlidingWindow((1, 64), 64, 1, bits=8)
    bands = SlidingWindow((1, 64), 64, 1, bits=8, estimators=("s1", "s2", "s3", "band_ratio"))
    assert engine_bytes_per_pixel(bands) - engine_bytes_per_pixel(plain) == 2 * 16 * 16 + 2 * 8
