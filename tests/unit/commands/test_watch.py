"""`edgedsm watch` without a broker: settings from config + options, and what it prints."""

from __future__ import annotations

import argparse
import json
from datetime import datetime
from pathlib import Path

import numpy as np
import pytest

from edgedsm.commands import watch
from edgedsm.commands.watcher import Watcher
from edgedsm.errors import ConfigError
from edgedsm.messages import Alert, AlertKind, RegionState, StateReport, Stats
from edgedsm.publish import MqttSettings, encode_map


def _args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    watch.add_arguments(parser)
    return parser.parse_args(argv)


def test_settings_from_daemon_config_and_options(tmp_path):
    config = tmp_path / "line3.toml"
    config.write_text('[device]\nname = "line3"\n[mqtt]\nhost = "broker"\nport = 1884\nclient_id = "daemon"\n')
    settings = watch.settings_from_args(_args("-c", str(config), "--port", "1999"))
    assert (settings.host, settings.port, settings.device) == ("broker", 1999, "line3")
    assert settings.client_id is None  # never the daemon's own id
    assert watch.settings_from_args(_args("-c", str(config), "--device", "other")).device == "other"


def test_config_without_mqtt_table_or_bad_option(tmp_path):
    config = tmp_path / "c.toml"
    config.write_text("[device]\nname = 'x'\n")
    with pytest.raises(ConfigError, match="no \\[mqtt\\] table"):
        watch.settings_from_args(_args("-c", str(config)))
    with pytest.raises(ConfigError, match="port"):
        watch.settings_from_args(_args("--port", "0"))


def test_tls_options_turn_tls_on(tmp_path):
    ca = tmp_path / "ca.pem"
    ca.write_text("x")
    settings = watch.settings_from_args(_args("--ca-file", str(ca), "--insecure"))
    assert settings.tls is not None and settings.tls.ca_file == ca and settings.tls.insecure


class _Message:
    def __init__(self, topic: str, payload: bytes, retain: bool = False) -> None:
        self.topic, self.payload, self.retain = topic, payload, retain


def _watcher(tmp_path: Path | None = None, count: int | None = None) -> tuple[Watcher, list[str]]:
    lines: list[str] = []
    watcher = Watcher(MqttSettings(device="line3"), password=None, save_maps=tmp_path, count=count,
                            emit=lines.append)
    return watcher, lines


def _feed(watcher: Watcher, topic: str, payload: object, retain: bool = False) -> None:
    if isinstance(payload, Alert | StateReport | Stats):
        payload = payload.to_bytes()
    data = payload if isinstance(payload, bytes) else json.dumps(payload).encode()
    watcher._on_message(watcher.client, None, _Message(f"edgedsm/line3/{topic}", data, retain))


def test_prints_state_changes_only_and_alerts_once():
    watcher, lines = _watcher(count=2)
    _feed(watcher, "availability", b"online", retain=True)
    _feed(watcher, "availability", b"online")  # same again after a reconnection: not printed
    _feed(watcher, "state", _report(A=("wet", 0.5), B=("wet", None)))
    _feed(watcher, "state", _report(A=("drying", 0.25), B=("wet", None)))
    alert = Alert(kind=AlertKind.TRANSITION, region="A", from_state="wet", to_state="drying", activity=0.25,
                  seq=4, stream="s", reason="below wet_below for 60 s", t=1.7e9)
    _feed(watcher, "alerts", alert)
    _feed(watcher, "alerts", alert)  # a resend
    assert not watcher.done.is_set()
    _feed(watcher, "alerts", alert.model_copy(update={"seq": 5}))
    assert watcher.done.is_set()
    _feed(watcher, "cmd/laser/reply", {"ok": False, "command": "laser", "error": "bad", "request_id": 3,
                                       "result": None, "t": 1.7e9})
    _feed(watcher, "alerts", b"{not json")
    body = [line[25:] for line in lines]
    at = datetime.fromtimestamp(1.7e9).strftime("%H:%M:%S")
    assert body == [
        "availability  online (retained)",
        "state         A: wet (activity 0.5)",
        "state         B: wet",
        "state         A: wet -> drying (activity 0.25)",
        f"alert #4      A: wet -> drying (activity 0.25) [transition] at {at} - below wet_below for 60 s",
        f"alert #5      A: wet -> drying (activity 0.25) [transition] at {at} - below wet_below for 60 s",
        "command       laser: refused: bad (request 3)",
        body[7],
    ]
    assert body[7].startswith("unreadable    edgedsm/line3/alerts")


def _report(**regions: tuple[str, float | None]) -> StateReport:
    return StateReport(t=1.7e9, estimator="s2", regions={
        name: RegionState(region=name, state=state, since=1.7e9, activity=activity)
        for name, (state, activity) in regions.items()})


def test_malformed_payloads_are_shown_as_such_never_raised():
    watcher, lines = _watcher()
    _feed(watcher, "state", {"phase": 2})
    _feed(watcher, "alerts", {"type": "explosion", "t": 1.0})
    _feed(watcher, "alerts", b"[" * 100_000 + b"]" * 100_000)
    _feed(watcher, "cmd/dark/reply", b"[1, 2]")
    _feed(watcher, "alerts", b"\xff\xfe")
    body = [line[25:] for line in lines]
    assert len(body) == 5 and all(line.startswith("unreadable    edgedsm/line3/") for line in body)
    assert body[0].startswith("unreadable    edgedsm/line3/state: not a valid StateReport: t: Field required: "
                              "'{\"phase\": 2}'")
    assert "not a valid Alert: type: Input should be 'transition', 'reset', 'fault', 'warning' or 'stage'" in body[1]
    assert "recursion limit" in body[2] and body[2].endswith("...")
    assert "not a valid CommandReply" in body[3]
    assert "alerts: not a valid Alert" in body[4]
    assert not watcher.alerts_seen


def test_stats_line_says_health_and_storage_fault():
    watcher = Watcher(MqttSettings(device="line3"), password=None, show_stats=True,
                            emit=(lines := []).append)
    stats = Stats(t=1.7e9, frames=640, ready=True, fps=29.97, laser="on", estimator="s2", states={"A": "wet"},
                  mqtt={"connected": True, "storage_error": "database or disk is full"})
    _feed(watcher, "stats", stats)
    assert lines[0][25:] == ("stats         frames 640, 29.97 fps, laser on, ready, A wet, "
                             "storage: database or disk is full")


def test_maps_are_paired_by_crc_and_saved(tmp_path):
    watcher, lines = _watcher(tmp_path)
    old_png, old_meta = encode_map(np.eye(8), estimator="s1", seq=1)
    png, meta = encode_map(np.arange(48.0).reshape(6, 8), estimator="s1", seq=2)
    _feed(watcher, "map/s1/meta", old_meta)
    _feed(watcher, "map/s1", png)         # PNG of update 2 with the meta of update 1: wait
    assert lines == []
    _feed(watcher, "map/s1/meta", meta)   # its own meta arrives
    assert (tmp_path / "s1-0000000002.png").is_file()
    assert "map s1        #2 6x8 [0, 47] saved to" in lines[0]
    assert old_png != png


def test_a_state_shows_its_signal_when_it_is_not_ok():
    watcher, lines = _watcher()
    report = StateReport(t=1.7e9, estimator="s2", regions={
        "A": RegionState(region="A", state="dry", since=1.7e9, activity=0.01, signal="low"),
        "B": RegionState(region="B", state="wet", since=1.7e9, activity=0.4, signal="ok")})
    _feed(watcher, "state", report)
    held = report.model_copy(update={"regions": {**report.regions, "B": report.regions["B"].model_copy(
        update={"state": "drying", "signal": "saturated", "activity": None})}})
    _feed(watcher, "state", held)
    assert [line[25:] for line in lines] == ["state         A: dry (activity 0.01, signal low)",
                                             "state         B: wet (activity 0.4)",
                                             "state         B: wet -> drying (signal saturated)"]
