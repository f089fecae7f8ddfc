"""`--json` output for scripts, the topic base check-config prints, watch's default device."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from edgedsm.cli import main
from edgedsm.commands.cmd import parse_arguments
from edgedsm.commands.watcher import Watcher
from edgedsm.config import DaemonConfig
from edgedsm.errors import DataError
from edgedsm.messages import RegionState, StateReport
from edgedsm.publish.settings import MqttSettings

CONFIG = """
[camera]
uri = "sim:default"
[mqtt]
topic_prefix = "plant1/edgedsm"
[homeassistant]
[http]
listen = "127.0.0.1:9200"
[[regions]]
name = "panel"
wet_above = 0.9
dry_below = 0.5
"""


def test_check_config_prints_the_topic_base_it_will_use(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "line.toml"
    path.write_text(CONFIG)
    assert main(["check-config", str(path)]) == 0
    assert "topics plant1/edgedsm/camera1/..." in capsys.readouterr().out
    assert main(["check-config", str(path), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["topic_base"] == "plant1/edgedsm/camera1"
    assert summary["regions"] == ["panel"] and summary["ok"] is True
    assert (summary["homeassistant"], summary["http"]) == ("homeassistant", "127.0.0.1:9200")


def test_check_config_says_what_tau_c_can_measure(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "tau.toml"
    path.write_text(CONFIG.replace('uri = "sim:default"', 'uri = "sim:default"\nframe_interval_s = 0.05')
                    .replace("wet_above = 0.9\ndry_below = 0.5", "wet_below_s = 0.2\ndry_above_s = 0.5")
                    + "[estimator]\nwindow = 100\nlag = 5\nmax_lag = 20\n")
    assert main(["check-config", str(path)]) == 0
    line = "τc: lags 1,2,3,4,6,8,11,15,20 (longest K = 20) at Δt = 0.05 s: measured from 0.0167 s to 1 s"
    assert line in capsys.readouterr().out
    assert main(["check-config", str(path), "--json"]) == 0
    tau = json.loads(capsys.readouterr().out)["tau_c"]
    assert tau["max_lag"] == 20 and tau["longest_s"] == pytest.approx(1.0)
    assert tau["shortest_s"] == pytest.approx(0.05 / 3)
    path.write_text(CONFIG)  # τc off: no line, null in JSON
    assert main(["check-config", str(path)]) == 0
    assert "τc" not in capsys.readouterr().out


def test_a_bad_config_still_exits_78_with_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "bad.toml"
    path.write_text(CONFIG.replace('listen = "127.0.0.1:9200"', 'listen = "127.0.0.1:99999"'))
    assert main(["check-config", str(path), "--json"]) == 78
    captured = capsys.readouterr()
    assert captured.out == "" and "http.listen" in captured.err


def test_homeassistant_without_mqtt_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "ha.toml"
    path.write_text('[camera]\nuri = "sim:default"\n[homeassistant]\n')
    assert main(["check-config", str(path)]) == 78
    assert "[homeassistant] needs [mqtt]" in capsys.readouterr().err


def test_one_device_name_default_everywhere() -> None:
    config = DaemonConfig.model_validate({"camera": {"uri": "sim:default"}, "mqtt": {}})
    assert config.device.name == MqttSettings().device == config.mqtt.device == "camera1"


def test_probe_json_is_the_only_thing_on_stdout(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["probe", "camera", "sim:default?time_scale=0", "--frames", "5", "--json"]) == 0
    captured = capsys.readouterr()
    result = json.loads(captured.out)
    assert result["frames"] == 5 and result["width"] > 0 and result["height"] > 0
    assert 0 <= result["saturated"] <= 1 and result["min"] <= result["mean"] <= result["max"]
    assert "grey levels" in captured.err


def test_analyze_json(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    frames = np.random.default_rng(3).integers(0, 255, (12, 8, 8)).astype(np.uint8)
    np.save(tmp_path / "frames.npy", frames)
    assert main(["analyze", str(tmp_path / "frames.npy"), "--estimator", "s1", "--lag", "2",
                 "-o", str(tmp_path / "s1.npy"), "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    saved = np.load(tmp_path / "s1.npy")
    assert result["mean"] == pytest.approx(float(saved.mean())) and result["shape"] == [8, 8]
    assert (result["window"], result["lag"], result["png"]) == (12, 2, None)


def test_watch_json_lines_one_object_per_event() -> None:
    lines: list[str] = []
    watcher = Watcher(MqttSettings(device="line3"), password=None, emit=lines.append, json_lines=True)
    watcher._availability_message("online", True)
    report = StateReport(t=1.0, estimator="s2", regions={
        "panel": RegionState(region="panel", state="wet", since=0.5, activity=0.4)})
    watcher._state_message(report)
    events = [json.loads(line) for line in lines]
    assert [e["event"] for e in events] == ["availability", "state"]
    assert events[0]["value"] == "online" and events[0]["retained"] is True
    assert (events[1]["region"], events[1]["state"], events[1]["from"], events[1]["activity"]) == \
        ("panel", "wet", None, 0.4)


@pytest.mark.parametrize(("text", "why"), [("[1]", "JSON object"), ("{", "not JSON"),
                                           ('{"request_id": 1}', "request_id")])
def test_cmd_refuses_bad_args_before_connecting(text: str, why: str) -> None:
    with pytest.raises(DataError, match=why):
        parse_arguments(text)
