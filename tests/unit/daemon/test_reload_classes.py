"""Which reload keeps the measurement and which restarts it (issue 10 §1), the state report's
republishing rule, and one device-name default everywhere."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from edgedsm.commands import cmd, watch
from edgedsm.config import DaemonConfig, load_config
from edgedsm.daemon.reload import KEEP, RESTART, SECTION_CHANGE, changed_sections, restart_reasons
from edgedsm.daemon.sinks import wanted_sinks
from edgedsm.dashboard.app import regions_from_configs
from edgedsm.errors import ConfigError
from edgedsm.messages import RegionState, StateReport
from edgedsm.publish.settings import DEFAULT_DEVICE
from edgedsm.publish.topics import Topics

BASE = """
[device]
name = "line3"
state_dir = "{state}"

[camera]
uri = "sim:default"

[estimator]
window = {window}

[[regions]]
name = "{region}"
shape = "rect"
x = 0
y = 0
width = {width}
height = 16
wet_above = {wet}
dry_below = 0.1

[mqtt]
host = "127.0.0.1"
stats_interval_s = {stats}
{extra}
"""


def config(tmp_path: Path, *, window: int = 64, region: str = "plate", width: int = 16, wet: float = 0.5,
           stats: float = 1.0, extra: str = "") -> DaemonConfig:
    path = tmp_path / f"c{len(list(tmp_path.iterdir()))}.toml"
    path.write_text(BASE.format(state=tmp_path / "state", window=window, region=region, width=width, wet=wet,
                                stats=stats, extra=extra), encoding="utf-8")
    return load_config(path)


def test_the_table_names_every_config_section_once() -> None:
    assert set(SECTION_CHANGE) == set(DaemonConfig.model_fields)
    assert set(SECTION_CHANGE.values()) == {KEEP, RESTART}


def test_publishing_logging_and_thresholds_keep_the_measurement(tmp_path: Path) -> None:
    running = config(tmp_path)
    new = config(tmp_path, wet=0.7, stats=2.5, extra='username = "plant"')
    assert changed_sections(new, running) == ["regions", "mqtt", "cadence"]
    assert restart_reasons(new, running) == []
    assert restart_reasons(config(tmp_path), running) == []  # unchanged


@pytest.mark.parametrize(("change", "reasons"), [
    ({"window": 32}, ["estimator"]),
    ({"width": 8}, ["regions"]),
    ({"region": "board"}, ["regions"]),
    ({"window": 32, "region": "board", "wet": 0.9}, ["estimator", "regions"]),
])
def test_measurement_changes_restart_and_say_why(tmp_path: Path, change: dict[str, object],
                                                 reasons: list[str]) -> None:
    assert restart_reasons(config(tmp_path, **change), config(tmp_path)) == reasons  # type: ignore[arg-type]


def test_only_the_sinks_whose_settings_changed_are_rebuilt(tmp_path: Path) -> None:
    running = wanted_sinks(config(tmp_path, extra="[homeassistant]\n[http]\n"))
    assert list(running) == ["mqtt", "homeassistant", "http"]
    thresholds = wanted_sinks(config(tmp_path, wet=0.8, extra="[homeassistant]\n[http]\n"))
    assert thresholds == running
    renamed = wanted_sinks(config(tmp_path, region="board", extra="[homeassistant]\n[http]\n"))
    assert [name for name in running if running[name] != renamed[name]] == ["homeassistant"]
    cadence = wanted_sinks(config(tmp_path, stats=3.0, extra="[homeassistant]\n[http]\n"))
    assert cadence == running  # applied to the running loop: no new session
    broker = wanted_sinks(config(tmp_path, extra='username = "plant"\n[homeassistant]\n[http]\n'))
    assert [name for name in running if running[name] != broker[name]] == ["mqtt", "homeassistant"]


def _report(state: str = "drying", activity: float | None = 0.2, ttd: float | None = 300.0,
            since: float = 1000.0) -> StateReport:
    return StateReport(t=2000.0, estimator="s2", laser="on", regions={
        "plate": RegionState(region="plate", state=state, since=since, activity=activity, time_to_dry_s=ttd)})


@pytest.mark.parametrize(("new", "moved"), [
    (_report(), False),
    (_report(activity=0.2099), False),            # 4.95 % of 0.2
    (_report(activity=0.2101), True),             # 5.05 %
    (_report(ttd=275.0), False),                  # 25 s: under both 10 % (30 s) and 30 s
    (_report(ttd=269.0), True),                   # 31 s
    (_report(ttd=None), True),
    (_report(state="dry"), True),
    (_report(since=1001.0), True),
])
def test_a_state_report_is_republished_when_it_moved_meaningfully(new: StateReport, moved: bool) -> None:
    assert new.moved_from(_report()) is moved


def test_the_cadence_once_in_mqtt_moves_to_its_own_table_with_a_note(tmp_path: Path) -> None:
    old = config(tmp_path, stats=2.5)  # written in [mqtt], as the BASE template does
    assert old.cadence.stats_interval_s == 2.5 and old.cadence.maps_interval_s == 60.0
    assert old.notes == [f"{old.source}: mqtt.stats_interval_s is deprecated: write it as stats_interval_s "
                         "in [cadence] (same meaning)"]
    new_path = tmp_path / "new.toml"
    new_path.write_text(BASE.replace("stats_interval_s = {stats}\n", "").format(
        state=tmp_path / "state", window=64, region="plate", width=16, wet=0.5, stats=0,
        extra="\n[cadence]\nstats_interval_s = 2.5\n"), encoding="utf-8")
    new = load_config(new_path)
    assert new.notes == [] and changed_sections(new, old) == []  # the same settings, where they belong
    both = tmp_path / "both.toml"
    both.write_text(BASE.format(state=tmp_path / "state", window=64, region="plate", width=16, wet=0.5, stats=1.0,
                                extra="\n[cadence]\nstats_interval_s = 2.5\n"), encoding="utf-8")
    with pytest.raises(ConfigError, match=r"mqtt\.stats_interval_s: given in both \[mqtt\] and \[cadence\]"):
        load_config(both)


def test_one_device_name_default_for_daemon_watch_cmd_dashboard_sparkplug(tmp_path: Path) -> None:
    assert DEFAULT_DEVICE == "camera1"
    path = tmp_path / "bare.toml"
    path.write_text('[camera]\nuri = "sim:default"\n\n[mqtt]\n\n[sparkplug]\ngroup_id = "plant"\n', encoding="utf-8")
    daemon = load_config(path)
    assert daemon.device.name == daemon.mqtt.device == daemon.sparkplug.edge_node_id == DEFAULT_DEVICE  # type: ignore[union-attr]
    watch_args = argparse.Namespace(config=None, host=None, port=None, topic_prefix=None, device=None, username=None,
                                    tls=False, ca_file=None, cert_file=None, key_file=None, insecure=False)
    assert Topics.from_settings(watch.settings_from_args(watch_args)).base == f"edgedsm/{DEFAULT_DEVICE}"
    parser = argparse.ArgumentParser()
    cmd.add_arguments(parser)
    cmd_args = parser.parse_args(["laser"])  # every option at its default
    assert Topics.from_settings(cmd.settings_of(cmd_args)).base == f"edgedsm/{DEFAULT_DEVICE}"
    assert list(regions_from_configs([path])) == [DEFAULT_DEVICE]


@pytest.mark.parametrize("laser", ["sim:line3", "serial:/dev/ttyUSB0?protocol=lcus&channel=1"])
def test_an_unchanged_file_changes_nothing_once_its_specs_were_read(tmp_path: Path, laser: str) -> None:
    # the running config has parsed its camera and relay URIs (cached on the sections); a fresh
    # parse of the same file has not: the sections' settings are still the same
    running = config(tmp_path, extra=f'\n[laser]\nuri = "{laser}"\n')
    assert running.laser is not None
    running.laser.spec, running.camera.spec  # noqa: B018  (what the daemon reads while running)
    new = config(tmp_path, extra=f'\n[laser]\nuri = "{laser}"\n')
    assert changed_sections(new, running) == []
    assert restart_reasons(new, running) == []
    moved = config(tmp_path, extra='\n[laser]\nuri = "sim:other"\n')
    assert restart_reasons(moved, running) == ["laser"]


def test_a_changed_recording_table_rebuilds_only_the_recorder_and_keeps_the_measurement(tmp_path: Path) -> None:
    from edgedsm.daemon.sinks import SinkSet

    running = config(tmp_path, extra=f'[recording]\ndir = "{tmp_path / "rec"}"\nmode = "alerts"\n')
    changed = config(tmp_path, extra=f'[recording]\ndir = "{tmp_path / "rec"}"\nmode = "continuous"\n')
    assert changed_sections(changed, running) == ["recording"] and restart_reasons(changed, running) == []
    running.mqtt = changed.mqtt = None  # the log sink: no broker needed
    sinks = SinkSet(lambda name, command: {})
    try:
        assert sinks.apply(running) == ["log", "recording"]
        first = sinks.recorder
        assert first is not None and first.mode == "alerts" and first in sinks.fanout.sinks
        assert sinks.apply(changed) == ["recording"]
        second = sinks.recorder
        assert second is not first and second is not None and second.mode == "continuous"
        assert first._closed and not second._closed  # the old one takes no more frames
        without = config(tmp_path)
        without.mqtt = None
        assert sinks.apply(without) == ["recording"] and sinks.recorder is None
        assert second._closed
    finally:
        sinks.close(1.0)
