"""The last commissioning report over the dashboard's HTTP API (edgedsm.dashboard.commissioning):
found from the daemon configs, shown when present, a clear message when absent or unreadable,
never a 500."""

from __future__ import annotations

import json
import threading
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from edgedsm.dashboard.commissioning import PNG_MAGIC, report_dirs
from edgedsm.dashboard.history import History
from edgedsm.dashboard.plant import Plant
from edgedsm.dashboard.server import DashboardServer, EventHub

CHOICE = {"estimator": "s2", "label": "S2 above noise, N=100 m=5 sliding", "noise_floor": True, "window": 100,
          "lag": 5, "mode": "sliding", "auc": 1.0, "d_prime": 21.3, "delay_s": -0.5, "timing_error_s": 0.5,
          "cost_ms_per_frame": 0.0134, "robust": True, "false_per_hour": 0.0, "sound": True,
          "regions": {"plate": {"auc": 1.0, "delay_s": -0.5, "false_transitions": 0, "transitions": [],
                                "thresholds": {"wet_above": 0.4887, "dry_below": 0.3837, "hysteresis": 0.05,
                                               "min_dwell_s": 3.0}}}}
SUMMARY = {"run": "reference.tif", "frames": 1300, "dt_s": 0.05, "wet_until_s": 10.0, "dry_from_s": 50.0,
           "seconds": 12.5, "passes": ["N=100 m=5 sliding"], "skipped": [], "reason": "S2 above noise ... calls",
           "recommended": CHOICE, "pareto": [CHOICE["label"]], "candidates": [CHOICE, CHOICE], "not_scored": [],
           "written_at": "2026-12-03T09:00:00+00:00", "command": "edgedsm tune reference.tif -c line3.toml",
           "config": "/etc/edgedsm/line3.toml", "device": "line3", "plots": ["activity.png", "tradeoff.png"]}


@pytest.fixture
def served(tmp_path: Path) -> Iterator[tuple[DashboardServer, dict[str, Path]]]:
    folders = {name: tmp_path / name for name in ("present", "absent", "corrupt", "wrong", "huge")}
    for name, folder in folders.items():
        if name != "absent":
            folder.mkdir()
    (folders["present"] / "summary.json").write_text(json.dumps(SUMMARY))
    (folders["present"] / "activity.png").write_bytes(PNG_MAGIC + b"activity")
    (folders["present"] / "tradeoff.png").write_bytes(b"<script>not a png</script>")
    (folders["corrupt"] / "summary.json").write_bytes(b'{"run": "x", "frames": 13\xff')
    (folders["wrong"] / "summary.json").write_text(json.dumps({**SUMMARY, "recommended": {**CHOICE, "window": "N"}}))
    (folders["huge"] / "summary.json").write_text("[" + "0," * (9 * 1024 * 1024) + "0]")
    history = History(tmp_path / "history.sqlite3", retention_s=3600.0)
    plant = Plant("edgedsm", history, lambda kind, data: None, {})
    server = DashboardServer(("127.0.0.1", 0), plant, history, EventHub(), token=None, send_command=None,
                             commissioning_dirs=folders)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield server, folders
    server.stop()
    thread.join(5)
    history.close()


def get(server: DashboardServer, path: str) -> tuple[int, bytes, str]:
    try:
        with urllib.request.urlopen(server.url.rstrip("/") + path, timeout=5) as answer:
            return answer.status, answer.read(), answer.headers["Content-Type"]
    except urllib.error.HTTPError as exc:
        with exc:
            return exc.code, exc.read(), exc.headers["Content-Type"]


def report(server: DashboardServer, device: str) -> dict[str, Any]:
    status, body, kind = get(server, f"/api/commissioning?device={device}")
    assert (status, kind) == (200, "application/json")
    return json.loads(body)


def test_a_present_report_is_served_cut_down_to_what_the_page_shows(served) -> None:
    server, folders = served
    answer = report(server, "present")
    shown = answer["report"]
    assert answer["message"] is None and answer["folder"] == str(folders["present"])
    assert shown["recommended"]["regions"]["plate"]["thresholds"] == CHOICE["regions"]["plate"]["thresholds"]
    assert (shown["recommended"]["label"], shown["recommended"]["window"], shown["recommended"]["lag"]) == (
        CHOICE["label"], 100, 5)
    assert (shown["candidates"], shown["written_at"], shown["run"]) == (2, SUMMARY["written_at"], "reference.tif")
    assert "transitions" not in shown["recommended"]["regions"]["plate"] and "not_scored" not in shown
    assert get(server, "/api/commissioning/activity.png?device=present") == (200, PNG_MAGIC + b"activity", "image/png")
    # what is not a PNG is not served as one, nor any other file of the folder
    assert get(server, "/api/commissioning/tradeoff.png?device=present")[0] == 404
    assert get(server, "/api/commissioning/summary.json?device=present")[0] == 404
    assert get(server, "/api/commissioning/..%2Fpresent%2Factivity.png?device=present")[0] == 404


@pytest.mark.parametrize(("device", "message"), [
    ("absent", "no commissioning report yet: `edgedsm tune RUN -c CONFIG ...` with this device's config keeps its "
               "last one in {folder}"),
    ("corrupt", "the commissioning report {folder}/summary.json cannot be read: 'utf-8' codec can't decode byte 0xff"),
    ("wrong", "the commissioning report {folder}/summary.json cannot be read: recommended.window: Input should be a "
              "valid integer"),
    ("huge", "the commissioning report {folder}/summary.json cannot be read: larger than 16 MiB"),
    ("nobody", "no daemon config names the device nobody: give the dashboard its config"),
])
def test_an_absent_or_unreadable_report_is_a_clear_message_not_an_error(served, device: str, message: str) -> None:
    server, folders = served
    answer = report(server, device)
    folder = folders.get(device)
    assert answer["report"] is None and answer["message"].startswith(message.format(folder=folder)), answer
    assert get(server, f"/api/commissioning/activity.png?device={device}")[0] == 404
    assert get(server, "/api/commissioning")[0] == 400  # which device: required


def test_each_device_has_its_folder_from_its_daemon_config(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setenv("STATE_DIRECTORY", str(tmp_path / "state"))
    (tmp_path / "etc").mkdir()
    (tmp_path / "etc" / "line3.toml").write_text('[device]\nname = "line3"\nstate_dir = "/var/lib/x"\n')
    (tmp_path / "etc" / "line4.toml").write_text('[device]\nname = "line4"\ncommissioning_dir = "tuned/line4"\n')
    (tmp_path / "etc" / "line5.toml").write_text('[camera]\nuri = "sim:default"\n')  # no [device]: the defaults
    (tmp_path / "etc" / "bad.toml").write_text('[device]\nname = "no spaces allowed"\n')
    found = report_dirs(sorted((tmp_path / "etc").glob("*.toml")))
    assert found == {"line3": Path("/var/lib/x/commissioning"), "line4": tmp_path / "etc" / "tuned" / "line4",
                     "camera1": tmp_path / "state" / "commissioning"}
