"""The dashboard's kinetics curve in a real browser (issue 37, part 3): a real mosquitto, a daemon
with ``[kinetics]`` on and two drying stages on the demo plate (config/scenes/drying_demo.toml at
64², 100 frames/s: τ 0.15 -> 15 s of the scene's time in about 10 s), `edgedsm dashboard` as a
process and Debian's chromium (headless).

Checked: the curve's y axis is logarithmic (a decade is the same height wherever it is); the
curve holds exactly the database's τ readings; each stage threshold is a dashed line at its τ
(its pixels on the canvas), each stage the daemon reached (its `stage` alert, stored in the
database) a mark at the alert's time (its pixels too); readings without a number (a made-up
device's dark, above, below) are gaps with their status, bounds as triangles, never a point of
the curve. Set EDGEDSM_DOCS_SCREENSHOTS=docs to refresh docs/dashboard-kinetics.png (taken while
the page lists the plant's one daemon only).
"""

from __future__ import annotations

import base64
import json
import os
import sqlite3
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import paho.mqtt.client as mqtt
import pytest
from helpers_daemon import DRYING_SCENE, Daemon, base_config, write_config
from helpers_dashboard import DashboardProcess, make_browser, severe_console_messages, wait_for
from helpers_mqtt import REPO, Broker
from paho.mqtt.enums import CallbackAPIVersion

pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.xdist_group("dashboard_kinetics_browser")]

DT = 0.05  # the scene's frame interval: the kinetics' seconds are the scene's
STAGES = [{"name": "set_to_touch", "rate_below_hz": 2.0},  # τ 0.5 s = 10 frames
          {"name": "tack_free", "rate_below_hz": 0.2}]  # τ 5 s = 100 frames
STAGE_RGB = (142, 68, 173)  # kinetics.js: #8e44ad
MARK_RGB = (192, 57, 43)  # kinetics.js: #c0392b


@dataclass
class Plant:
    broker: Broker
    daemon: Daemon
    dashboard: DashboardProcess
    browser: Any
    database: Path
    shots: Path

    def js(self, script: str, *args: Any) -> Any:
        return self.browser.execute_script(script, *args)

    def load_history(self) -> int:
        return self.browser.execute_async_script(
            "const done = arguments[arguments.length - 1]; window.edgedsmDashboard.loadHistory().then(done);")


@pytest.fixture(scope="module")
def plant(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Plant]:
    tmp = tmp_path_factory.mktemp("dashboard-kinetics")
    broker = Broker(tmp / "broker").start()
    scene = tmp / "plate64.toml"
    scene.write_text(DRYING_SCENE.read_text().replace("size = 128", "size = 64"))
    config = base_config(tmp / "plate-k", device="plate-k", camera=f"sim:{scene}?time_scale=0.2", port=broker.port)
    config["camera"]["frame_interval_s"] = DT
    config["cadence"]["stats_interval_s"] = 0.25
    config["kinetics"] = {"enabled": True, "longest_age_s": 30.0, "stage_dwell_s": 0.5, "trend_window_s": 5.0}
    config["kinetics.stages"] = STAGES  # [[kinetics.stages]]
    path = write_config(tmp / "plate-k.toml", config)
    database = tmp / "history.sqlite3"
    dashboard = DashboardProcess(["--broker", f"127.0.0.1:{broker.port}", "--listen", "127.0.0.1:0",
                                  "--database", str(database), "-c", str(path)])
    wait_for(lambda: json.loads(dashboard.get("/api/info"))["broker_connected"], 10,
             "the dashboard subscribed (before the daemon's stage alerts: alerts are not retained)")
    daemon = Daemon(path)
    browser = None
    try:
        browser = make_browser(tmp / "chromium-profile")
        browser.get(dashboard.url)
        shots = Path(os.environ.get("EDGEDSM_DOCS_SCREENSHOTS") or tmp)
        yield Plant(broker, daemon, dashboard, browser, database, shots if shots.is_absolute() else REPO / shots)
    finally:
        if browser is not None:
            browser.quit()
        daemon.kill()
        dashboard.stop()
        broker.stop()


def _stage_alerts(database: Path) -> list[tuple[float, str]]:
    with sqlite3.connect(database, timeout=5) as db:
        return db.execute("SELECT t, reason FROM alerts WHERE device = 'plate-k' AND region = 'plate' "
                          "AND kind = 'stage' ORDER BY t").fetchall()


def _canvas(plant: Plant) -> np.ndarray:
    """The plot canvas's own bitmap (toDataURL), RGB: what uPlot drew, in canvas pixels. An
    element screenshot is the compositor's picture and lagged the last draw under load."""
    url = plant.js("return document.querySelector('#kinetics-plot canvas').toDataURL('image/png')")
    png = base64.b64decode(url.split(",", 1)[1])
    return cv2.cvtColor(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB).astype(int)


def _near(pixels: np.ndarray, rgb: tuple[int, int, int]) -> np.ndarray:
    return np.abs(pixels - np.array(rgb)).sum(axis=-1) < 60


def _no_errors(plant: Plant) -> None:
    assert severe_console_messages(plant.browser) == []
    assert plant.dashboard.errors == []


@pytest.mark.timeout(150)
def test_the_kinetics_curve_is_on_a_log_axis_with_the_stages_drawn_and_marked(plant: Plant) -> None:
    wait_for(lambda: len(_stage_alerts(plant.database)) == 2, 90, "both drying stages reached (the daemon's alerts)")
    time.sleep(1.0)  # a few more readings beyond tack-free
    plant.daemon.terminate()  # no live reading redraws the curve between what is read and what is seen
    plant.js("window.edgedsmDashboard.select('plate-k')")
    wait_for(lambda: plant.js("return document.getElementById('region-select').value") == "plate", 10,
             "plate-k's region on the page")
    count = plant.load_history()
    assert count > 0
    wait_for(lambda: plant.js("return window.edgedsmDashboard.kinetics()")["points"], 10, "the kinetics curve")
    plant.js("document.querySelector('#kinetics-plot canvas').scrollIntoView({block: 'center'})")
    time.sleep(0.5)  # uPlot draws after setData returns (a microtask): the hook's record is the last draw's
    state = plant.js("return window.edgedsmDashboard.kinetics()")
    assert plant.js("return document.getElementById('kinetics-box').hidden") is False
    # a log axis: uPlot's logarithmic distribution, and every decade the same height on the canvas
    assert state["distr"] == 3 and state["view"] == "tau"
    ys = plant.js("return window.edgedsmDashboard.kineticsPos([0.1, 1, 10])")
    assert ys[0] - ys[1] > 20 and (ys[0] - ys[1]) == pytest.approx(ys[1] - ys[2], rel=1e-6), ys
    # the curve: the database's τ readings point for point, no number where the status has none
    with sqlite3.connect(plant.database, timeout=5) as db:
        rows = db.execute("SELECT t, kinetics_tau_s, kinetics_status FROM samples WHERE device = 'plate-k' AND "
                          "region = 'plate' AND kinetics_status IS NOT NULL ORDER BY t").fetchall()
    plotted = state["points"]
    assert len(rows) >= 20 and len(plotted) >= len(rows) - 2  # live stats may have added a reading or two
    for (t, tau, status), (x, y) in zip(rows, plotted, strict=False):
        assert x == pytest.approx(t, abs=1e-6)
        assert (y is None and status != "ok") or (status == "ok" and y == pytest.approx(tau, rel=1e-9))
    taus = [tau for _, tau, status in rows if status == "ok"]
    assert min(taus) < 0.5 and max(taus) > 5.0, (min(taus), max(taus))  # the plate dried past both stages
    canvas = _canvas(plant)
    assert plant.js("return window.edgedsmDashboard.kinetics()") == state  # no draw since: the canvas shows it
    drawn = state["drawn"]
    # each stage threshold a dashed line at its τ (1/rate), across the plot
    assert [line["name"] for line in drawn["lines"]] == ["set_to_touch", "tack_free"]
    for line, stage in zip(drawn["lines"], STAGES, strict=True):
        assert line["value"] == pytest.approx(1.0 / stage["rate_below_hz"])
        assert line["y"] == pytest.approx(plant.js("return window.edgedsmDashboard.kineticsPos([arguments[0]])[0]",
                                                   line["value"]))
        row = round(line["y"])
        coloured = _near(canvas[row - 1:row + 2], STAGE_RGB).any(axis=0).mean()
        assert coloured > 0.4, f"{stage['name']}: {coloured:.0%} of the row in the stage colour"
    # each stage reached a mark at its alert's time, named
    alerts = _stage_alerts(plant.database)
    assert [mark["name"] for mark in drawn["marks"]] == ["set_to_touch", "tack_free"]
    assert [reason.split()[2] for _, reason in alerts] == ["set_to_touch", "tack_free"]
    for mark, (t, _) in zip(drawn["marks"], alerts, strict=True):
        assert mark["t"] == pytest.approx(t, abs=1e-6)
        column = round(mark["x"])
        coloured = _near(canvas[:, column - 1:column + 2], MARK_RGB).any(axis=1).mean()
        assert coloured > 0.5, f"{mark['name']}: {coloured:.0%} of the column in the mark colour"
    # the marks are where the curve crossed the lines: τ at the mark at or above the stage's
    for mark, stage in zip(drawn["marks"], STAGES, strict=True):
        before = [tau for t, tau, status in rows if status == "ok" and t <= mark["t"] + 1e-6]
        assert before and max(before[-3:]) >= 0.8 / stage["rate_below_hz"], (stage, before[-3:])
    # every gap is a reading without a number, never a point
    assert all(gap["status"] != "ok" for gap in drawn["gaps"])
    panel = plant.browser.find_element("id", "kinetics-box")
    plant.js("arguments[0].scrollIntoView()", panel)
    names = plant.js("return [...document.querySelectorAll('.device-card')].map(c => c.dataset.device)")
    assert names == ["plate-k"]  # the screenshot shows the plant's daemon only
    panel.screenshot(str(plant.shots / "dashboard-kinetics.png"))
    # the rate view: the same log axis, the lines at the stages' rates
    plant.js("window.edgedsmDashboard.kineticsView('rate')")
    rate = plant.js("return window.edgedsmDashboard.kinetics()")
    assert rate["distr"] == 3 and [line["value"] for line in rate["drawn"]["lines"]] == [2.0, 0.2]
    assert [y for _, y in rate["points"]][:len(plotted)] == [None if y is None else pytest.approx(1.0 / y)
                                                             for _, y in plotted]
    plant.js("window.edgedsmDashboard.kineticsView('tau')")
    _no_errors(plant)


@pytest.mark.timeout(60)
def test_readings_without_a_number_are_gaps_with_their_status_never_points(plant: Plant) -> None:
    """A made-up device (after the screenshot): dark, above and below between readings of τ."""
    publisher = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="kinetics-test-publisher")
    publisher.connect("127.0.0.1", plant.broker.port)
    publisher.loop_start()
    try:
        start = time.time() - 30
        readings = [("ok", 0.2, None), ("ok", 0.4, None), ("dark", None, None), ("dark", None, None),
                    ("ok", 1.0, None), ("above", None, 28.0), ("above", None, 28.0), ("below", None, 0.05),
                    ("ok", 2.0, None)]
        for i, (status, tau, bound) in enumerate(readings):
            reading = {"status": status, **({"tau_s": tau, "rate_hz": 1 / tau} if tau else {}),
                       **({"bound_s": bound} if bound else {})}
            stats = {"t": start + i, "frames": 10 * i, "ready": True, "fps": 20.0, "laser": "on", "estimator": "s2",
                     "state": {"panel": "drying"}, "kinetics": {"panel": reading}}
            publisher.publish("edgedsm/line-k/stats", json.dumps(stats), qos=1).wait_for_publish(5)
        wait_for(lambda: len(json.loads(plant.dashboard.get(
            f"/api/history?device=line-k&region=panel&from={start - 1}"))["kinetics"]) == len(readings), 10,
            "the made-up readings in the history")
    finally:
        publisher.loop_stop()
        publisher.disconnect()
    plant.js("window.edgedsmDashboard.select('line-k')")
    wait_for(lambda: plant.js("return document.getElementById('region-select').value") == "panel", 10, "line-k")
    assert plant.load_history() == len(readings)
    state = plant.js("return window.edgedsmDashboard.kinetics()")
    assert [y for _, y in state["points"]] == [0.2, 0.4, None, None, 1.0, None, None, None, 2.0]
    # one labelled gap per run of one status; above/below a triangle at the bound, none for dark
    assert [gap["status"] for gap in state["drawn"]["gaps"]] == ["dark", "above", "below"]
    assert [(b["status"], b["value"]) for b in state["drawn"]["bounds"]] == [("above", 28.0), ("above", 28.0),
                                                                            ("below", 0.05)]
    # no stage configured for it (not in a -c config): no lines, no marks
    assert state["drawn"]["lines"] == [] and state["drawn"]["marks"] == []
    _no_errors(plant)
