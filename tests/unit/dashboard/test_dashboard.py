"""The dashboard without a broker or a browser: the plant view fed payloads directly (valid,
hostile, duplicated), the SQLite history, and the HTTP API on a loopback port."""

from __future__ import annotations

import json
import re
import socket
import sqlite3
import threading
import time
import tomllib
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pydantic import TypeAdapter

from edgedsm.config import RegionSection
from edgedsm.dashboard import history as history_module
from edgedsm.dashboard.history import History, Sample
from edgedsm.dashboard.plant import MAX_DEVICES, Plant, RegionInfo
from edgedsm.dashboard.server import DashboardServer, EventHub
from edgedsm.messages import (
    Alert,
    AlertKind,
    MapStats,
    RegionActivity,
    RegionSignal,
    RegionState,
    RegionTau,
    StateReport,
    Stats,
)
from edgedsm.publish.mapcodec import encode_map

#: A whole second of today: the history keeps a day, so a fixed date would age out of it.
NOW = float(int(time.time()))


#: The plain S2 mean above the judged activity (the noise floor a daemon takes off)
FLOOR = 0.0625


def stats(t: float, activity: float, state: str = "drying") -> bytes:
    """Stats whose judged ``activity`` is above a noise floor of FLOOR: the plain mean is higher."""
    plain = activity + FLOOR
    per_map = {"s2": MapStats(pixels=100, mean=plain, std=0.01, p05=0.1, median=plain, p95=0.4)}
    judged = {"plate": RegionActivity(value=activity, estimator="s2", unit="1", basis="above_noise")}
    return Stats(t=t, frames=10, ready=True, fps=20.0, laser="on", estimator="s2", regions={"plate": per_map},
                 states={"plate": state}, drops={"dropped_queue": 2}, ambient_level=3.5,
                 activity=judged).to_bytes()


@pytest.fixture
def plant(history: History) -> Plant:
    events: list[tuple[str, dict[str, Any]]] = []
    regions = {"cam1": {"plate": RegionInfo("plate", {"shape": "rect", "x": 0, "y": 0, "width": 8, "height": 8},
                                            0.3, 0.16)}}
    made = Plant("edgedsm", history, lambda kind, data: events.append((kind, data)), regions, clock=lambda: NOW)
    made.events = events  # type: ignore[attr-defined]
    return made


def test_stats_state_and_alerts_reach_the_view_and_the_history(plant: Plant, history: History) -> None:
    plant.handle("edgedsm/cam1/availability", b"online")
    plant.handle("edgedsm/cam1/stats", stats(NOW, 0.25))
    plant.handle("edgedsm/cam1/stats", stats(NOW + 1, 0.20))
    report = StateReport(t=NOW, estimator="s2", laser="on",
                         regions={"plate": RegionState(region="plate", state="drying", since=NOW - 5, activity=0.2)})
    plant.handle("edgedsm/cam1/state", report.to_bytes())
    alert = Alert(kind=AlertKind.TRANSITION, t=NOW, region="plate", from_state="wet", to_state="drying",
                  seq=3, stream="abc")
    plant.handle("edgedsm/cam1/alerts", alert.to_bytes())
    plant.handle("edgedsm/cam1/alerts", alert.to_bytes())  # at-least-once: a resend
    plant.handle("edgedsm/cam1/cmd/rebaseline/reply", b"{}")  # not the dashboard's business
    (device,) = plant.snapshot()
    assert device["availability"] == "online" and device["rejected"] == 0
    # the judged value under `activity` (what the history and the chart carry), the plain mean beside it
    assert device["stats"]["activity"] == {"plate": 0.20}
    assert device["stats"]["drops"] == {"dropped_queue": 2, "dropped_invalid": 0}
    assert device["stats"]["plain"] == {"plate": 0.20 + FLOOR} and device["stats"]["plain_label"] == "S2 mean"
    assert device["stats"]["judged"] == {"plate": {"estimator": "s2", "unit": None, "label": "S2",
                                                   "basis": "above_noise"}}
    assert device["state"]["regions"]["plate"]["state"] == "drying"
    assert len(device["alerts"]) == 1 and device["regions"]["plate"]["wet_above"] == 0.3
    assert [kind for kind, _ in plant.events].count("alert") == 1  # type: ignore[attr-defined]
    assert history.flush(5)
    assert history.samples("cam1", "plate", NOW - 10, NOW + 10) == [(NOW, 0.25, "drying"), (NOW + 1, 0.20, "drying")]
    assert [a["to"] for a in history.alerts("cam1", "plate", NOW - 10, NOW + 10)] == ["drying"]


def test_a_region_judged_on_tau_c_shows_its_tau_c_beside_others_on_s2(plant: Plant, history: History) -> None:
    per_map = {"s2": MapStats(pixels=100, mean=0.25, std=0.01, p05=0.1, median=0.25, p95=0.4)}
    report = StateReport(t=NOW, estimator="s2", laser="on", regions={
        "plate": RegionState(region="plate", state="wet", since=NOW - 5, activity=0.25),
        "edge": RegionState(region="edge", state="drying", since=NOW - 5, activity=0.31, estimator="tau_c",
                            tau_c_status="measured")})
    plant.handle("edgedsm/cam1/state", report.to_bytes())
    message = Stats(t=NOW, frames=10, ready=True, fps=20.0, laser="on", estimator="s2",
                    regions={"plate": per_map, "edge": per_map}, states={"plate": "wet", "edge": "drying"},
                    tau_c={"plate": RegionTau(tau_c_s=0.12, status="measured"),
                           "edge": RegionTau(tau_c_s=0.31, status="measured")})
    plant.handle("edgedsm/cam1/stats", message.to_bytes())
    (device,) = plant.snapshot()
    # a daemon whose stats carry no `activity` yet: the state report's judged values, never the plain mean
    assert device["stats"]["activity"] == {"plate": 0.25, "edge": 0.31}  # S2 for one, τc (s) for the other
    assert device["stats"]["judged"]["edge"] == {"estimator": "tau_c", "unit": "s", "label": "τc",
                                                 "basis": "state report"}
    assert history.flush(5)
    assert history.samples("cam1", "edge", NOW - 1, NOW + 1) == [(NOW, 0.31, "drying")]


def test_each_regions_signal_quality_reaches_the_view(plant: Plant) -> None:
    plant.handle("edgedsm/cam1/stats", stats(NOW, 0.25))  # estimator.noise_floor off: no signal
    assert plant.snapshot()[0]["stats"]["signal"] == {}
    light = RegionSignal(signal="dark", mean=12.5, dark_fraction=0.75, saturated_fraction=0.0, speckle_contrast=0.5,
                         noise_floor=0.25, above_noise=0.0625, above_noise_spread=0.03125, noise_model="frames",
                         intensity_change=0.125, reason="signal dark: 75% of the pixels dark (mean 12.5 grey levels)")
    message = Stats.model_validate_json(stats(NOW + 1, 0.2)).model_copy(update={"signal": {"plate": light}})
    plant.handle("edgedsm/cam1/stats", message.to_bytes())
    (device,) = plant.snapshot()
    assert device["rejected"] == 0 and device["stats"]["signal"] == {"plate": {
        "signal": "dark", "mean": 12.5, "dark_fraction": 0.75, "saturated_fraction": 0.0, "speckle_contrast": 0.5,
        "noise_floor": 0.25, "above_noise": 0.0625, "above_noise_spread": 0.03125, "noise_model": "frames",
        "intensity_change": 0.125, "reason": "signal dark: 75% of the pixels dark (mean 12.5 grey levels)"}}
    crowded = message.model_copy(update={"signal": {f"r{i}": light for i in range(65)}})
    plant.handle("edgedsm/cam1/stats", crowded.to_bytes())
    assert plant.snapshot()[0]["rejected"] == 1 and "more than 64 regions" in plant.snapshot()[0]["last_rejection"]


def test_the_colour_pictures_for_home_assistant_are_not_unreadable(plant: Plant) -> None:
    plant.handle("edgedsm/cam1/stats", stats(NOW, 0.25))
    for name in ("s1", "s2", "s3"):  # the daemon's documented topics with [homeassistant] on
        plant.handle(f"edgedsm/cam1/map/{name}/color", b"\x89PNG\r\n\x1a\n" + bytes(40))
    (device,) = plant.snapshot()
    assert device["rejected"] == 0 and device["last_rejection"] is None and device["maps"] == {}
    plant.handle("edgedsm/cam1/map/s2/colour", b"x")  # not a documented topic: still refused, and said
    assert plant.snapshot()[0]["rejected"] == 1


# Named ids: NOW in an id would differ between pytest-xdist's workers (they collect at different
# seconds and must agree on every test's name).
@pytest.mark.parametrize(("topic", "payload", "reason"), [
    ("stats", b"\xff{ not json", "not a valid Stats"),
    ("stats", json.dumps({"t": "yesterday"}).encode(), "not a valid Stats: t"),
    ("state", json.dumps({"t": NOW, "estimator": "s2", "regions": {"a": {"state": "soggy"}}}).encode(),
     "not a valid StateReport"),
    ("alerts", json.dumps([1, 2]).encode(), "not a valid Alert"),
    ("availability", b"maybe", "availability must be online or offline"),
    ("stats", b"{" + b" " * (300 * 1024) + b"}", "payload of"),
    ("map/s2/meta", b"[1]", "must be a JSON object"),
    ("map/s2", b"\x89PNG\r\n\x1a\n" + bytes(10 * 1024 * 1024), "map picture of 10485768 bytes"),
    ("map/s2", b"GIF89a" + bytes(40), "not a PNG"),
    ("map/s2", b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x01\x00\x00\x00\x00\x10\x00" + bytes(40), "65536x4096"),
], ids=["stats-not-json", "stats-bad-time", "state-unknown-state", "alerts-not-objects", "availability-maybe",
        "stats-too-long", "meta-not-object", "map-too-long", "map-not-png", "map-too-many-pixels"])
def test_hostile_payloads_are_counted_with_a_reason_and_break_nothing(plant: Plant, topic: str, payload: bytes,
                                                                       reason: str) -> None:
    plant.handle(f"edgedsm/cam1/{topic}", payload)
    (device,) = plant.snapshot()
    assert device["rejected"] == 1 and reason in device["last_rejection"] and device["maps"] == {}
    plant.handle("edgedsm/cam1/stats", stats(NOW, 0.3))  # still works
    assert plant.snapshot()[0]["stats"]["activity"] == {"plate": 0.3}


def test_a_map_is_decoded_once_picture_and_meta_pair_up(plant: Plant) -> None:
    values = np.linspace(0.1, 0.5, 64 * 48).reshape(64, 48)
    _png, meta = encode_map(values, estimator="s2", seq=7, t=NOW, window=100, lag=5)
    other_png, other_meta = encode_map(values[::-1] * 2, estimator="s2", seq=8, t=NOW, window=100, lag=5)
    plant.handle("edgedsm/cam1/map/s2/meta", json.dumps(meta).encode())
    plant.handle("edgedsm/cam1/map/s2", other_png)  # the picture of another update: waits
    assert plant.map_image("cam1", "s2") is None
    plant.handle("edgedsm/cam1/map/s2/meta", json.dumps(other_meta).encode())
    image = plant.map_image("cam1", "s2")
    assert image is not None and image.meta["seq"] == 8 and image.png.startswith(b"\x89PNG")
    np.testing.assert_allclose(image.values, values[::-1] * 2, atol=other_meta["scale"])


def test_devices_beyond_the_bound_are_ignored(plant: Plant) -> None:
    for index in range(MAX_DEVICES + 5):
        plant.handle(f"edgedsm/cam{index}/availability", b"online")
    assert len(plant.snapshot()) == MAX_DEVICES and plant.ignored == 5


def test_history_keeps_its_retention_and_buckets_long_ranges(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    store = History(tmp_path / "h.sqlite3", retention_s=3600.0)
    now = time.time()
    for i in range(100):
        store.add(Sample("cam", "plate", now - 7200 + i, 1.0, "wet"))  # older than the retention
        store.add(Sample("cam", "plate", now - 100 + i, float(i), "drying"))
    assert store.flush(5)
    store.prune()
    assert len(store.samples("cam", "plate", now - 10_000, now)) == 100
    monkeypatch.setattr(history_module, "MAX_POINTS", 10)
    buckets = store.samples("cam", "plate", now - 100, now)
    assert 9 <= len(buckets) <= 11
    assert buckets[0][1] == pytest.approx(4.5, abs=1.0)  # the mean of the first bucket of 0, 1, 2, ...
    store.close()
    with sqlite3.connect(tmp_path / "h.sqlite3") as db:
        assert db.execute("PRAGMA journal_mode").fetchone() == ("wal",)
        indexes = {row[1] for row in db.execute("PRAGMA index_list(samples)")}
    assert "samples_by_region" in indexes


# -- the HTTP API -------------------------------------------------------------------------------

TOKEN = "s3cret-token-of-16+chars"


@pytest.fixture
def server(plant: Plant, history: History) -> Iterator[tuple[DashboardServer, list[tuple[str, str]]]]:
    sent: list[tuple[str, str]] = []

    def send(device: str, command: str) -> None:
        if command not in ("rebaseline", "dark", "publish_maps"):
            raise ValueError(f"command {command!r} is not allowed from the dashboard")
        sent.append((device, command))

    made = DashboardServer(("127.0.0.1", 0), plant, history, EventHub(), token=TOKEN, send_command=send)
    thread = threading.Thread(target=made.serve_forever, daemon=True)
    thread.start()
    yield made, sent
    made.stop()
    thread.join(5)


def call(server: DashboardServer, path: str, body: dict[str, Any] | bytes | None = None,
         headers: dict[str, str] | None = None) -> tuple[int, bytes]:
    data = body if isinstance(body, bytes) or body is None else json.dumps(body).encode()
    request = urllib.request.Request(server.url.rstrip("/") + path, data=data, headers=headers or {})
    try:
        with urllib.request.urlopen(request, timeout=5) as answer:
            return answer.status, answer.read()
    except urllib.error.HTTPError as exc:
        with exc:
            return exc.code, exc.read()


def test_history_as_json_and_csv(server: tuple[DashboardServer, Any], plant: Plant, history: History) -> None:
    plant.handle("edgedsm/cam1/stats", stats(NOW, 0.25))
    plant.handle("edgedsm/cam1/stats", stats(NOW + 1, 0.2, "dry"))
    assert history.flush(5)
    status, body = call(server[0], f"/api/history?device=cam1&region=plate&from={NOW - 5}&to={NOW + 5}")
    answer = json.loads(body)
    assert status == 200 and answer["points"] == [[NOW, 0.25, "drying"], [NOW + 1, 0.2, "dry"]]
    assert answer["thresholds"] == {"wet_above": 0.3, "dry_below": 0.16}
    status, body = call(server[0], f"/api/history?device=cam1&region=plate&from={NOW - 5}&to={NOW + 5}&format=csv")
    assert status == 200 and body.decode().splitlines() == [
        "t,device,region,activity,state", f"{NOW},cam1,plate,0.25,drying", f"{NOW + 1},cam1,plate,0.2,dry"]
    assert call(server[0], "/api/history?device=cam1&region=plate&from=nan")[0] == 400
    assert call(server[0], "/api/history?device=cam1")[0] == 400


def test_region_statistics_and_a_toml_block_the_daemon_accepts(server: tuple[DashboardServer, Any],
                                                              plant: Plant) -> None:
    values = np.arange(64 * 64, dtype=float).reshape(64, 64) / 4096
    png, meta = encode_map(values, estimator="s2", seq=1, t=NOW, window=100, lag=5)
    plant.handle("edgedsm/cam1/map/s2/meta", json.dumps(meta).encode())
    plant.handle("edgedsm/cam1/map/s2", png)
    shape = {"shape": "rect", "x": 10, "y": 20, "width": 8, "height": 4}
    status, body = call(server[0], "/api/region-stats", {"device": "cam1", "map": "s2", "name": "edge", "shape": shape})
    answer = json.loads(body)
    assert status == 200 and answer["stats"]["pixels"] == 32
    assert answer["stats"]["mean"] == pytest.approx(values[20:24, 10:18].mean(), abs=meta["scale"])
    region = TypeAdapter(RegionSection).validate_python(tomllib.loads(answer["toml"])["regions"][0])
    assert region.name == "edge" and region.shape == "rect" and region.width == 8
    bad = {"device": "cam1", "map": "s2", "shape": {"shape": "polygon", "points": [[0, 0], [1, 1]]}}
    status, body = call(server[0], "/api/region-stats", bad)
    assert status == 400 and b"points" in body


def test_commands_need_the_token_and_never_switch_the_laser(server: tuple[DashboardServer, Any]) -> None:
    made, sent = server
    body = {"device": "cam1", "command": "rebaseline"}
    assert call(made, "/api/command", body)[0] == 401
    assert call(made, "/api/command", body, {"Authorization": "Bearer wrong"})[0] == 401
    assert call(made, "/api/command", body, {"Authorization": f"Bearer {TOKEN}"})[0] == 200
    laser = {"device": "cam1", "command": "laser"}
    assert call(made, "/api/command", laser, {"Authorization": f"Bearer {TOKEN}"})[0] == 400
    assert sent == [("cam1", "rebaseline")]
    made.token = None
    assert call(made, "/api/command", body, {"Authorization": f"Bearer {TOKEN}"})[0] == 403


def test_only_the_page_files_are_served_and_bodies_are_bounded(server: tuple[DashboardServer, Any]) -> None:
    made = server[0]
    status, page = call(made, "/")
    assert status == 200 and b"/static/vendor/uPlot.iife.min.js" in page
    assert re.findall(rb'(?:src|href)="(?!/|data:|#)', page) == []  # everything from the dashboard itself (no CDN)
    assert call(made, "/static/vendor/uPlot.iife.min.js")[0] == 200
    assert call(made, "/static/../server.py")[0] == 404
    assert call(made, "/static/%2e%2e/server.py")[0] == 404
    assert call(made, "/api/region-stats", b"x" * (65 * 1024))[0] == 400
    assert call(made, "/api/region-stats", b"[1]")[0] == 400


def test_malformed_queries_are_refused_not_crashed(server: tuple[DashboardServer, Any]) -> None:
    made = server[0]
    many = "&".join(f"k{i}=1" for i in range(30))
    assert call(made, f"/api/devices?{many}")[0] == 400
    assert call(made, "/api/map.png?device=nobody&name=s2")[0] == 404
    assert call(made, "/api/history?device=a&region=b&from=10&to=5")[0] == 400
    assert call(made, "/api/devices")[0] == 200


def test_command_line_errors_are_one_line_with_exit_78(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    from edgedsm.cli import main

    database = str(tmp_path / "h.sqlite3")
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        assert main(["dashboard", "--database", database, "--listen", f"127.0.0.1:{port}"]) == 78
    assert f"--listen 127.0.0.1:{port}:" in capsys.readouterr().err
    assert main(["dashboard", "--database", database, "--config-dir", str(tmp_path / "none")]) == 78
    assert "--config-dir" in capsys.readouterr().err
    monkeypatch.setenv("EDGEDSM_DASHBOARD_TOKEN", "short")
    assert main(["dashboard", "--database", database]) == 78
    assert "at least 16 characters" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:
        main(["dashboard", "--listen", "127.0.0.1:http"])
    assert exit_info.value.code == 2


def test_region_outlines_and_thresholds_come_from_the_daemon_configs(tmp_path: Path) -> None:
    from edgedsm.dashboard.app import regions_from_configs

    config = tmp_path / "line3.toml"
    config.write_text('[device]\nname = "line3"\n[[regions]]\nname = "edge"\nshape = "circle"\ncx = 5\ncy = 6\n'
                      'radius = 4\nwet_above = 0.3\ndry_below = 0.1\n[[regions]]\nname = "all"\nwet_above = 2\n'
                      'dry_below = 1\n')
    found = regions_from_configs([config])
    assert found["line3"]["edge"] == RegionInfo("edge", {"shape": "circle", "cx": 5, "cy": 6, "radius": 4}, 0.3, 0.1)
    assert found["line3"]["all"].shape == {"shape": "full"} and found["line3"]["all"].wet_above == 2.0
