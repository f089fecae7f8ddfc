"""The plant dashboard in a real browser: a real mosquitto, two daemons on simulated cameras
(a plate that dries, a plate that stays wet, different regions), `edgedsm dashboard` as a
process, and Debian's chromium (headless) driven by Selenium.

Checked: the page lists every device; a state change on MQTT shows on the page within 2 s; the
map is drawn (the screenshot's pixels match the map the server serves); the history plot holds
exactly the points the database holds; hostile payloads are shown escaped and break nothing;
the last `edgedsm tune` report of a device's config is shown with the thresholds it proposed;
no console errors. Set EDGEDSM_DOCS_SCREENSHOTS=docs to refresh the screenshots in docs/: they
are taken only while the page lists the plant's two plates (the tests' made-up devices, a hostile
name among them, come after the last one).
"""

from __future__ import annotations

import json
import os
import re
import sqlite3
import subprocess
import sys
import time
import tomllib
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
from helpers_mqtt import REPO, Broker, child_env
from paho.mqtt.enums import CallbackAPIVersion
from pydantic import TypeAdapter

from edgedsm.config import RegionSection

# One pytest-xdist worker for the module: its tests share one plant (the module fixture: broker,
# two daemons, dashboard, browser), started once and seen by the tests in their order.
pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.xdist_group("dashboard_browser")]

STILL_WET_SCENE = """
[scene]
size = 128
frames = 1000000
seed = 5
speckle_size = 2.0
dt = 0.05
[activity]
tau_c = 2.0
[detector]
n_max = 1000
bits = 8
"""
SHOW_S = 2.0  # a change on MQTT must be on the page within this
TOKEN = "commissioning-token-42"


@dataclass
class Plant:
    broker: Broker
    daemons: dict[str, Daemon]
    dashboard: DashboardProcess
    browser: Any
    database: Path
    publisher: mqtt.Client
    shots: Path
    commands: list[tuple[str, bytes]]
    configs: dict[str, Path]

    def publish(self, topic: str, payload: bytes | str | dict, retain: bool = False) -> None:
        data = json.dumps(payload) if isinstance(payload, dict) else payload
        self.publisher.publish(topic, data, qos=1, retain=retain).wait_for_publish(5)

    def js(self, script: str, *args: Any) -> Any:
        return self.browser.execute_script(script, *args)

    def card_text(self, device: str) -> str:
        return self.js("const c = document.querySelector(`.device-card[data-device=\"${arguments[0]}\"]`);"
                       "return c ? c.textContent : null;", device) or ""

    def get(self, path: str) -> bytes:
        return self.dashboard.get(path)


def _config(tmp: Path, device: str, camera: str, port: int, regions: list[dict[str, Any]]) -> Path:
    config = base_config(tmp / device, device=device, camera=camera, port=port)
    config["cadence"]["maps_interval_s"] = 2.0
    config["cadence"]["stats_interval_s"] = 0.5
    config["regions"] = regions
    return write_config(tmp / f"{device}.toml", config)


@pytest.fixture(scope="module")
def plant(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Plant]:
    tmp = tmp_path_factory.mktemp("dashboard")
    broker = Broker(tmp / "broker").start()
    (tmp / "wet.toml").write_text(STILL_WET_SCENE)
    drying = _config(tmp, "plate-a", f"sim:{DRYING_SCENE}?time_scale=0.2", broker.port,
                     [{"name": "plate", "wet_above": 0.24, "dry_below": 0.10, "hysteresis": 0.05, "min_dwell_s": 1.0}])
    wet = _config(tmp, "plate-b", f"sim:{tmp / 'wet.toml'}?time_scale=0.5", broker.port,
                  [{"name": "left", "shape": "rect", "x": 8, "y": 8, "width": 48, "height": 110, "wet_above": 0.24,
                    "dry_below": 0.10, "min_dwell_s": 1.0},
                   {"name": "spot", "shape": "circle", "cx": 92, "cy": 64, "radius": 26, "wet_above": 0.24,
                    "dry_below": 0.10, "min_dwell_s": 1.0}])
    database = tmp / "history.sqlite3"
    dashboard = DashboardProcess(["--broker", f"127.0.0.1:{broker.port}", "--listen", "127.0.0.1:0",
                                  "--database", str(database), "-c", str(drying), "-c", str(wet)],
                                 env={"EDGEDSM_DASHBOARD_TOKEN": TOKEN})
    wait_for(lambda: json.loads(dashboard.get("/api/info"))["broker_connected"], 10,
              "the dashboard subscribed (before the daemons' first alerts: alerts are not retained)")
    daemons = {"plate-a": Daemon(drying), "plate-b": Daemon(wet)}
    replies: list[tuple[str, bytes]] = []
    publisher = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="dashboard-test-publisher")
    publisher.on_message = lambda client, userdata, message: replies.append((message.topic, message.payload))
    publisher.connect("127.0.0.1", broker.port)
    publisher.subscribe("edgedsm/+/cmd/#", qos=1)
    publisher.loop_start()
    browser = None
    try:
        browser = make_browser(tmp / "chromium-profile")
        browser.get(dashboard.url)
        shots = Path(os.environ.get("EDGEDSM_DOCS_SCREENSHOTS") or tmp)
        if not shots.is_absolute():
            shots = REPO / shots
        yield Plant(broker, daemons, dashboard, browser, database, publisher, shots, replies,
                    {"plate-a": drying, "plate-b": wet})
    finally:
        if browser is not None:
            browser.quit()
        publisher.loop_stop()
        publisher.disconnect()
        for daemon in daemons.values():
            daemon.kill()
        dashboard.stop()
        broker.stop()


def _shot(plant: Plant, name: str, element: Any = None) -> None:
    """Save a screenshot (the page, or ``element``) as ``name`` in the shots folder (docs/ with
    EDGEDSM_DOCS_SCREENSHOTS=docs): only while the page lists the plant's own devices, never one
    the tests made up (a hostile name in the README's picture)."""
    names = plant.js("return [...document.querySelectorAll('.device-card')].map(c => c.dataset.device)")
    assert sorted(names) == sorted(plant.daemons), f"{name}: the page lists made-up devices too: {names}"
    target = plant.shots / name
    if element is None:
        plant.browser.save_screenshot(str(target))
    else:
        element.screenshot(str(target))


def _no_errors(plant: Plant, allowed: str | None = None) -> None:
    """No console errors (``allowed``: a message the test caused on purpose)."""
    messages = severe_console_messages(plant.browser)
    assert [message for message in messages if allowed is None or not re.search(allowed, message)] == []
    assert plant.dashboard.errors == []


@pytest.mark.timeout(90)
def test_every_device_is_listed_and_its_map_is_drawn(plant: Plant) -> None:
    wait_for(lambda: "plate: " in plant.card_text("plate-a") and "spot: " in plant.card_text("plate-b"), 40,
             "both daemons' regions on the page")
    names = plant.js("return [...document.querySelectorAll('.device-card')].map(c => c.dataset.device)")
    assert sorted(names) == ["plate-a", "plate-b"]
    assert "online" in plant.card_text("plate-a") and "online" in plant.card_text("plate-b")

    plant.js("window.edgedsmDashboard.select('plate-b')")
    wait_for(lambda: plant.js("const i = document.getElementById('map-img'); "
                              "return i.complete && i.naturalWidth > 0 && !i.closest('[hidden]')"), 30, "the map image")
    time.sleep(0.3)  # let the overlay and colour bar settle
    src = plant.js("return document.getElementById('map-img').getAttribute('src')")
    served = cv2.imdecode(np.frombuffer(plant.get(src), np.uint8), cv2.IMREAD_COLOR)
    frame = plant.browser.find_element("id", "map-frame")
    shot = cv2.imdecode(np.frombuffer(frame.screenshot_as_png, np.uint8), cv2.IMREAD_COLOR)
    expected = cv2.resize(served, (shot.shape[1], shot.shape[0]), interpolation=cv2.INTER_NEAREST)
    difference = np.abs(shot.astype(int) - expected.astype(int)).mean()
    blank = np.abs(shot.astype(int) - 255).mean()
    assert shot.std() > 10, "the map area is flat: nothing drawn"
    assert difference < 20, f"the drawn map differs from the served one by {difference:.1f} levels on average"
    assert blank > 60
    outlines = plant.js("return [...document.querySelectorAll('#map-overlay text')].map(t => t.textContent)")
    assert sorted(outlines) == ["left", "spot"]
    # each region row carries its signal quality (estimator.noise_floor, on by default) as a badge
    badges = "return [...document.querySelectorAll('#regions tr.region-row')].map(r => [r.dataset.region, " \
             "(r.querySelector('.badge.signal') || {}).textContent])"
    verdicts = ("ok", "low", "dark", "saturated", "not speckle")
    wait_for(lambda: sorted(name for name, verdict in plant.js(badges) if verdict in verdicts) == ["left", "spot"],
             30, "a signal badge in each region row")
    _shot(plant, "dashboard.png")
    _no_errors(plant)


@pytest.mark.timeout(60)
def test_a_region_drawn_on_the_map_gets_statistics_and_a_toml_block(plant: Plant) -> None:
    from selenium.webdriver import ActionChains

    plant.js("window.edgedsmDashboard.select('plate-b')")
    wait_for(lambda: plant.js("const i = document.getElementById('map-img'); return i.complete && i.naturalWidth > 0"),
             30, "the map of plate-b")
    plant.browser.find_element("css selector", "[data-tool=rect]").click()
    overlay = plant.browser.find_element("id", "map-overlay")
    size = overlay.size["width"]  # 384 CSS px for the 128 px map: 3 screen px per map px
    (ActionChains(plant.browser).move_to_element_with_offset(overlay, -size // 2 + 42, -size // 2 + 42)
     .click_and_hold().move_by_offset(60, 45).move_by_offset(60, 45).release().perform())
    toml_text = wait_for(lambda: plant.js("return document.getElementById('editor-toml').value"), 10, "the TOML")
    region = TypeAdapter(RegionSection).validate_python(tomllib.loads(toml_text)["regions"][0])
    assert region.shape == "rect" and region.name == "new_region"
    assert (region.x, region.y, region.width, region.height) == pytest.approx((14, 14, 40, 30), abs=1.0)
    answer = json.loads(plant.dashboard.post("/api/region-stats", {
        "device": "plate-b", "map": plant.js("return document.getElementById('map-select').value"),
        "shape": {"shape": "rect", "x": region.x, "y": region.y, "width": region.width, "height": region.height}}))
    shown = plant.js("return document.getElementById('editor-stats').textContent")
    assert answer["stats"]["pixels"] >= 1000 and shown.startswith(f"{answer['stats']['pixels']} px")
    _shot(plant, "dashboard-editor.png")
    _no_errors(plant)


@pytest.mark.timeout(60)
def test_a_command_from_the_page_needs_the_token_and_reaches_the_daemon(plant: Plant) -> None:
    plant.js("window.edgedsmDashboard.select('plate-b')")
    buttons = plant.js("return [...document.querySelectorAll('[data-command]')].map(b => b.dataset.command)")
    assert buttons == ["rebaseline", "dark", "publish_maps"]  # never the laser
    button = plant.browser.find_element("css selector", "[data-command=publish_maps]")
    plant.browser.find_element("id", "token").send_keys("wrong-token-wrong-token")
    button.click()
    wait_for(lambda: "wrong or missing token" in plant.js("return document.getElementById('command-result')"
                                                          ".textContent"), 5, "the refusal of a wrong token")
    assert not [topic for topic, _ in plant.commands if topic.startswith("edgedsm/plate-b/cmd/publish_maps")]
    token = plant.browser.find_element("id", "token")
    token.clear()
    token.send_keys(TOKEN)
    button.click()
    reply = wait_for(lambda: next((json.loads(payload) for topic, payload in plant.commands
                                   if topic == "edgedsm/plate-b/cmd/publish_maps/reply"), None), 10,
                     "the daemon's reply to publish_maps")
    assert reply["ok"] is True and str(reply["request_id"]).startswith("dashboard-")
    _no_errors(plant, allowed=r"/api/command - Failed to load resource: .* 401 \(Unauthorized\)$")


@pytest.mark.timeout(120)
def test_the_history_plot_has_the_points_the_database_has(plant: Plant) -> None:
    plant.js("window.edgedsmDashboard.select('plate-a')")
    # the rectangle drawn on plate-b's map, its numbers and the command's answer stayed with plate-b
    assert plant.js("return [document.querySelectorAll('#map-overlay .drawn').length, "
                    "document.getElementById('editor-stats').textContent, "
                    "document.getElementById('editor-toml').value, "
                    "document.getElementById('command-result').textContent]") == [0, "", "", ""]
    wait_for(lambda: re.search(r"plate: dry\b(?!ing)", plant.card_text("plate-a")), 60,
             "the drying plate to be dry on the page")
    time.sleep(1.0)
    _shot(plant, "dashboard-drying.png")
    plant.daemons["plate-a"].terminate()
    time.sleep(1.5)  # the dashboard commits every 0.5 s
    count = plant.browser.execute_async_script(
        "const done = arguments[arguments.length - 1]; window.edgedsmDashboard.loadHistory().then(done);")
    plotted = plant.js("return window.edgedsmDashboard.plotPoints()")
    with sqlite3.connect(plant.database, timeout=5) as db:
        rows = db.execute("SELECT t, activity FROM samples WHERE device = 'plate-a' AND region = 'plate' "
                          "ORDER BY t").fetchall()
        transitions = db.execute("SELECT to_state FROM alerts WHERE device = 'plate-a' AND kind = 'transition' "
                                 "ORDER BY t").fetchall()
    # a history (states every 0.5 s for the ~10 s the plate takes to dry), plotted point for point
    assert len(rows) >= 10 and count == len(rows) == len(plotted)
    for (t, activity), (x, y) in zip(rows, plotted, strict=True):
        assert x == pytest.approx(t, abs=1e-6)
        assert (y is None and activity is None) or y == pytest.approx(activity, rel=1e-9)
    page_alerts = next(d for d in json.loads(plant.get("/api/devices")) if d["device"] == "plate-a")["alerts"]
    # every transition reached the database (the first may be warming_up -> drying on a loaded machine)
    assert [to for (to,) in transitions] == [a["to"] for a in page_alerts if a["type"] == "transition"]
    assert transitions[-1] == ("dry",)
    assert plant.js("return window.edgedsmDashboard.thresholds()") == {"wet_above": 0.24, "dry_below": 0.10}
    csv_text = plant.get(f"/api/history?device=plate-a&region=plate&from={time.time() - 3600}&format=csv").decode()
    assert len(csv_text.strip().splitlines()) == len(rows) + 1
    _no_errors(plant)


@pytest.mark.timeout(180)
def test_the_last_commissioning_report_shows_the_thresholds_tune_proposed(plant: Plant, tmp_path: Path) -> None:
    from edgedsm.dashboard.commissioning import report_dirs

    wait_for(lambda: "plate: " in plant.card_text("plate-a"), 40, "plate-a on the page")
    plant.js("window.edgedsmDashboard.select('plate-a')")
    message = "return document.getElementById('commissioning-message').textContent"
    wait_for(lambda: plant.js(message).startswith("no commissioning report yet: `edgedsm tune RUN -c CONFIG ...`"),
             10, "the page to say there is no report yet")
    assert plant.js("return document.getElementById('commissioning-report').hidden") is True
    # a real tune with plate-a's config, on the demo plate at 64²: few candidates, about 10 s
    scene = tmp_path / "reference-plate.toml"
    scene.write_text(DRYING_SCENE.read_text().replace("size = 128", "size = 64"))
    tune = subprocess.run([sys.executable, "-m", "edgedsm", "tune", str(scene), "-c", str(plant.configs["plate-a"]),
                           "--frames", "1300", "--wet-until", "10", "--dry-from", "50", "--windows", "100",
                           "--lags", "5,10", "--estimators", "s2,s3,contrast", "--no-progress", "--json"],
                          capture_output=True, text=True, env=child_env(), timeout=150)
    assert tune.returncode == 0, tune.stderr
    summary = json.loads(tune.stdout)
    chosen = summary["recommended"]
    load = "const done = arguments[arguments.length - 1]; window.edgedsmDashboard.loadCommissioning().then(done);"
    shown = plant.browser.execute_async_script(load)
    assert shown["message"] is None and shown["report"]["recommended"]["label"] == chosen["label"]

    def text(element: str) -> str:
        return plant.js(f"return document.getElementById('commissioning-{element}').textContent")

    assert text("choice") == f"recommended: {chosen['label']}"
    assert (f'[estimator] activity = "{chosen["estimator"]}", window = {chosen["window"]}, lag = {chosen["lag"]}, '
            f'mode = "{chosen["mode"]}"') in text("numbers")
    assert text("reason") == summary["reason"] + "." and "d′" in text("reason")
    rows = plant.js("return [...document.querySelectorAll('#commissioning-regions tr.commissioning-region')].map(r => "
                    "[r.dataset.region, r.querySelector('.wet').textContent, r.querySelector('.dry').textContent])")
    assert [name for name, _, _ in rows] == list(chosen["regions"]) == ["plate"]
    for name, wet, dry in rows:
        proposed = chosen["regions"][name]["thresholds"]
        for shown_text in (wet, dry):  # "wet_above = 0.4887" (τc: "wet_below_s = 0.12 s")
            key, value = shown_text.removesuffix(" s").split(" = ")
            assert float(value) == proposed[key], (shown_text, proposed)
    assert re.match(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d UTC · run " + re.escape(str(scene)) + ": 1300 frames", text("run"))
    assert text("command").startswith(f"edgedsm tune {scene} -c {plant.configs['plate-a']}")
    for name in ("activity", "tradeoff"):
        wait_for(lambda name=name: plant.js(f"const i = document.getElementById('commissioning-{name}'); "
                                            "return i.complete && i.naturalWidth > 600 && !i.hidden"), 10,
                 f"the {name} plot")
    panel = plant.browser.find_element("id", "commissioning")
    plant.js("arguments[0].scrollIntoView()", panel)
    _shot(plant, "dashboard-commissioning.png", panel)

    # the report is another program's file: whatever text it holds is shown, never run
    hostile = '<img src=x onerror="window.tunePwned=1">'
    summary_file = report_dirs([plant.configs["plate-a"]])["plate-a"] / "summary.json"
    original = summary_file.read_text()
    data = json.loads(original)
    data["run"] = data["reason"] = data["command"] = data["recommended"]["label"] = hostile
    data["recommended"]["regions"] = {hostile: data["recommended"]["regions"]["plate"]}
    summary_file.write_text(json.dumps(data))
    plant.browser.execute_async_script(load)
    assert text("choice") == f"recommended: {hostile}" and text("command") == hostile and hostile in text("run")
    assert plant.js("return document.querySelector('#commissioning-regions td').textContent") == hostile
    assert plant.js("return window.tunePwned === undefined && document.querySelectorAll('img[src=\"x\"]').length "
                    "=== 0")
    summary_file.write_text(original)  # tune's own report again: the later screenshots show it, not the attack
    assert plant.browser.execute_async_script(load)["report"]["recommended"]["label"] == chosen["label"]
    _no_errors(plant)


@pytest.mark.timeout(60)
def test_an_offline_device_is_greyed_and_the_chart_draws_the_judged_activity(plant: Plant) -> None:
    # plate-a was stopped with SIGTERM (test_the_history_plot_has_the_points_the_database_has): its
    # retained state is its last word, and the page must not read it as now
    device = next(d for d in json.loads(plant.get("/api/devices")) if d["device"] == "plate-a")
    assert device["availability"] == "offline"
    assert device["state"]["availability"] == "offline" and device["state"]["laser"] == "off"
    plant.js("window.edgedsmDashboard.select('plate-a')")
    wait_for(lambda: plant.js("return document.querySelector('.device-card[data-device=\"plate-a\"]')"
                              ".classList.contains('stale')"), SHOW_S, "plate-a's card greyed")
    card = plant.card_text("plate-a")
    assert "laser off" in card and "fps" not in card, card
    line = plant.js("return document.getElementById('device-stats').textContent")
    assert line.startswith("offline laser off · last heard ") and "fps" not in line, line  # badge, then text
    assert line.endswith(" · the figures are the last received"), line
    rows = plant.js("return [...document.querySelectorAll('#regions tr.region-row')].map(r => [r.className, "
                    "r.querySelector('.time-to-dry').textContent, r.querySelector('.activity').textContent, "
                    "r.querySelector('.activity').title, r.querySelector('.plain').textContent])")
    assert len(rows) == 1
    classes, time_to_dry, activity, what, plain = rows[0]
    assert "stale" in classes.split() and time_to_dry == "–"
    # estimator.noise_floor is on by default: the activity column and the chart are S2 above the
    # noise floor, the plain S2 mean (higher by the floor) is its own column
    judged, mean = device["stats"]["activity"]["plate"], device["stats"]["plain"]["plate"]
    assert device["stats"]["judged"]["plate"] == {"estimator": "s2", "unit": None, "label": "S2",
                                                  "basis": "above_noise"}
    assert what == "S2 above the noise floor" and mean > judged
    assert activity == plant.js("return fmt(arguments[0])", judged) and plain == plant.js("return fmt(arguments[0])",
                                                                                         mean)
    plant.browser.execute_async_script(
        "const done = arguments[arguments.length - 1]; window.edgedsmDashboard.loadHistory().then(done);")
    assert plant.js("return window.edgedsmDashboard.plotCaption()") == \
        "S2 above the noise floor against wet_above (blue) and dry_below (green)"
    last = [y for _, y in plant.js("return window.edgedsmDashboard.plotPoints()") if y is not None][-1]
    assert last == pytest.approx(judged, rel=1e-9)  # the curve is the judged value, as the state report's
    plant.js("window.scrollTo(0, 0)")
    _shot(plant, "dashboard-offline.png")
    _no_errors(plant)


# The devices below are made up by the tests (one of them named to attack the page): they come after
# every screenshot, so that the docs' pictures show the plant's two plates only (_shot checks it).


@pytest.mark.timeout(60)
def test_a_state_change_on_mqtt_shows_within_2_s(plant: Plant) -> None:
    base = "edgedsm/line-x"
    plant.publish(f"{base}/availability", "online", retain=True)

    def report(state: str) -> dict[str, Any]:
        now = time.time()
        return {"t": now, "estimator": "s2", "laser": "on",
                "regions": {"panel": {"region": "panel", "state": state, "since": now, "activity": 0.2}}}

    plant.publish(f"{base}/state", report("wet"), retain=True)
    wait_for(lambda: "panel: wet" in plant.card_text("line-x"), 10, "the new device line-x")
    for state in ("drying", "dry"):
        started = time.monotonic()
        plant.publish(f"{base}/state", report(state), retain=True)
        wait_for(lambda state=state: f"panel: {state}" in plant.card_text("line-x"), SHOW_S, f"panel: {state}")
        assert time.monotonic() - started < SHOW_S
    plant.publish(f"{base}/availability", "offline", retain=True)
    wait_for(lambda: "offline" in plant.card_text("line-x"), SHOW_S, "line-x offline")
    _no_errors(plant)


@pytest.mark.timeout(60)
def test_a_regions_signal_shows_as_a_coloured_badge_with_its_reason(plant: Plant) -> None:
    base = "edgedsm/line-s"
    now = time.time()
    signal = {"signal": "saturated", "mean": 240.5, "dark_fraction": 0.0, "saturated_fraction": 0.25,
              "speckle_contrast": 0.5, "noise_floor": 0.125, "above_noise": 0.0625, "above_noise_spread": 0.03125,
              "reason": "signal saturated: 25% of the pixels reach full scale"}
    stats = {"t": now, "frames": 100, "ready": True, "fps": 20.0, "laser": "on", "estimator": "s2",
             "state": {"panel": "drying", "edge": "wet"},
             "signal": {"panel": signal, "edge": {**signal, "signal": "ok", "reason": None}}}
    plant.publish(f"{base}/stats", stats)
    wait_for(lambda: "panel: drying" in plant.card_text("line-s"), 10, "the new device line-s")
    plant.js("window.edgedsmDashboard.select('line-s')")
    row = ("const b = document.querySelector(`#regions tr.region-row[data-region=\"${arguments[0]}\"] .badge.signal`);"
           "return b && [b.textContent, getComputedStyle(b).backgroundColor, b.getAttribute('title'), "
           "b.closest('tr').querySelector('.above-noise').textContent];")
    wait_for(lambda: plant.js(row, "panel") is not None, SHOW_S, "the panel's signal badge")
    text, colour, title, above = plant.js(row, "panel")
    assert (text, colour) == ("saturated", "rgb(230, 162, 26)")  # amber: the light cannot be judged
    assert title.splitlines() == ["signal saturated: 25% of the pixels reach full scale",
                                  "mean 241 grey levels · dark 0 % · saturated 25 % · speckle contrast 0.50"]
    assert above == "0.0625 ± 0.031 (floor 0.125)"
    assert plant.js(row, "edge")[:2] == ["ok", "rgb(46, 158, 79)"]  # green
    _no_errors(plant)


@pytest.mark.timeout(60)
def test_hostile_payloads_are_escaped_and_break_nothing(plant: Plant) -> None:
    base = "edgedsm/evil"
    name = '<img src=x onerror="window.pwned=1">'
    now = time.time()
    plant.publish(f"{base}/state", {"t": now, "estimator": "s2",
                                    "regions": {name: {"region": name, "state": "wet", "since": now}}})
    wait_for(lambda: name in plant.card_text("evil"), 5, "the hostile region name shown as text")
    plant.publish(f"{base}/stats", b"\xff not json {")
    plant.publish(f"{base}/stats", {"t": "yesterday", "frames": -1})
    plant.publish(f"{base}/alerts", {"type": "transition", "t": [1]})
    plant.publish(f"{base}/map/s2/meta", {"shape": [4096, 4096], "offset": 0, "scale": 1})
    plant.publish(f"{base}/map/s2", b"\x89PNG\r\n\x1a\n" + os.urandom(10 * 1024 * 1024))
    plant.publish(f"{base}/map/s3", b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\x00\x01\x00\x00\x00\x01\x00\x00" + b"\0" * 64)
    wait_for(lambda: "5 unreadable" in plant.card_text("evil"), 10, "5 rejected payloads counted on the page")
    assert plant.js("return document.querySelectorAll('img[src=\"x\"]').length") == 0
    assert plant.js("return window.pwned === undefined")
    devices = json.loads(plant.get("/api/devices"))
    evil = next(d for d in devices if d["device"] == "evil")
    assert evil["rejected"] == 5 and evil["maps"] == {}
    # still live afterwards
    plant.publish(f"{base}/state", {"t": time.time(), "estimator": "s2",
                                    "regions": {name: {"region": name, "state": "drying", "since": now}}})
    wait_for(lambda: f"{name}: drying" in plant.card_text("evil"), SHOW_S, "a valid update after the hostile ones")
    _no_errors(plant)
