"""The dashboard keeps each region's kinetics ([kinetics] on; docs/kinetics.md): the stats' τ, rate
and status reach the view and the SQLite history (a database from before them gains the columns,
its rows kept), the history API answers them with the device's drying stages, long ranges keep a
bucket's last reading (never a mean over statuses without a number). The curve itself is drawn in
a browser: tests/integration/test_dashboard_kinetics_browser.py."""

from __future__ import annotations

import json
import sqlite3
import threading
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from edgedsm.dashboard import history as history_module
from edgedsm.dashboard.app import regions_from_configs
from edgedsm.dashboard.history import History, Sample
from edgedsm.dashboard.plant import Plant, RegionInfo
from edgedsm.dashboard.server import DashboardServer, EventHub
from edgedsm.messages import RegionKinetics, Stats

NOW = float(int(time.time()))
STAGES = [{"name": "set_to_touch", "rate_below_hz": 2.0}, {"name": "tack_free", "rate_below_hz": 0.2}]


def stats(t: float, **kinetics: RegionKinetics) -> bytes:
    return Stats(t=t, frames=10, ready=True, fps=20.0, laser="on", estimator="s2", states={"plate": "drying"},
                 kinetics=kinetics).to_bytes()


@pytest.fixture
def plant(history: History) -> Plant:
    regions = {"cam1": {"plate": RegionInfo("plate", {"shape": "full"}, 0.3, 0.1, STAGES)}}
    return Plant("edgedsm", history, lambda kind, data: None, regions, clock=lambda: NOW)


def test_the_kinetics_reach_the_view_and_the_history_never_a_number_without_one(plant: Plant,
                                                                                history: History) -> None:
    plant.handle("edgedsm/cam1/stats", stats(NOW, plate=RegionKinetics(status="warming_up")))
    plant.handle("edgedsm/cam1/stats", stats(NOW + 1, plate=RegionKinetics(status="ok", tau_s=0.4, rate_hz=2.5),
                                             shadow=RegionKinetics(status="dark")))
    plant.handle("edgedsm/cam1/stats", stats(NOW + 2, plate=RegionKinetics(
        status="above", bound_s=28.3, stages={"set_to_touch": NOW + 1.5}, next_stage="tack_free")))
    (device,) = plant.snapshot()
    assert device["rejected"] == 0
    assert device["stats"]["kinetics"]["plate"] == {"status": "above", "bound_s": 28.3, "tau_s": None, "rate_hz": None,
                                                   "frame": None, "stages": {"set_to_touch": NOW + 1.5},
                                                   "next_stage": "tack_free", "time_to_next_stage_s": None}
    assert device["regions"]["plate"]["stages"] == STAGES
    assert history.flush(5)
    assert history.kinetics("cam1", "plate", NOW - 1, NOW + 3) == [
        (NOW, None, "warming_up", None), (NOW + 1, 0.4, "ok", None), (NOW + 2, None, "above", 28.3)]
    # a region with a status and no state still gets its row; a region without kinetics has none
    assert history.kinetics("cam1", "shadow", NOW - 1, NOW + 3) == [(NOW + 1, None, "dark", None)]
    history.add(Sample("cam1", "other", NOW, 0.2, "wet"))
    assert history.flush(5) and history.kinetics("cam1", "other", NOW - 1, NOW + 1) == []


def test_a_database_from_before_the_kinetics_gains_its_columns_and_keeps_its_rows(tmp_path: Path) -> None:
    path = tmp_path / "old.sqlite3"
    with sqlite3.connect(path) as db:
        db.execute("CREATE TABLE samples (device TEXT NOT NULL, region TEXT NOT NULL, t REAL NOT NULL, "
                   "activity REAL, state TEXT)")
        db.execute("INSERT INTO samples VALUES ('cam1', 'plate', ?, 0.25, 'wet')", (NOW,))
    store = History(path, retention_s=86400.0)
    try:
        store.add(Sample("cam1", "plate", NOW + 1, 0.2, "drying", 1.5, "ok", None))
        assert store.flush(5)
        assert store.samples("cam1", "plate", NOW - 1, NOW + 2) == [(NOW, 0.25, "wet"), (NOW + 1, 0.2, "drying")]
        assert store.kinetics("cam1", "plate", NOW - 1, NOW + 2) == [(NOW + 1, 1.5, "ok", None)]
    finally:
        store.close()


def test_long_ranges_keep_each_buckets_last_reading(history: History, monkeypatch: pytest.MonkeyPatch) -> None:
    for i in range(100):  # τ 1, 2, ... with every tenth reading 'dark'
        dark = i % 10 == 9
        history.add(Sample("cam", "plate", NOW - 100 + i, None, "drying", None if dark else float(i + 1),
                           "dark" if dark else "ok", None))
    assert history.flush(5)
    monkeypatch.setattr(history_module, "MAX_POINTS", 10)
    buckets = history.kinetics("cam", "plate", NOW - 100, NOW)
    assert 9 <= len(buckets) <= 11
    for t, tau, status, _ in buckets:  # each bucket's reading is one that was stored at its time
        i = round(t - (NOW - 100))
        assert (status, tau) == (("dark", None) if i % 10 == 9 else ("ok", float(i + 1)))


@pytest.fixture
def server(plant: Plant, history: History) -> Iterator[DashboardServer]:
    made = DashboardServer(("127.0.0.1", 0), plant, history, EventHub(), token=None, send_command=None)
    thread = threading.Thread(target=made.serve_forever, daemon=True)
    thread.start()
    yield made
    made.stop()
    thread.join(5)


def get(server: DashboardServer, path: str) -> Any:
    with urllib.request.urlopen(server.url.rstrip("/") + path, timeout=5) as answer:
        return answer.read()


def test_the_history_api_answers_the_kinetics_and_the_stages(server: DashboardServer, plant: Plant,
                                                              history: History) -> None:
    plant.handle("edgedsm/cam1/stats", stats(NOW, plate=RegionKinetics(status="ok", tau_s=0.5, rate_hz=2.0)))
    plant.handle("edgedsm/cam1/stats", stats(NOW + 1, plate=RegionKinetics(status="below", bound_s=0.05)))
    assert history.flush(5)
    query = f"/api/history?device=cam1&region=plate&from={NOW - 5}&to={NOW + 5}"
    answer = json.loads(get(server, query))
    assert answer["kinetics"] == [[NOW, 0.5, "ok", None], [NOW + 1, None, "below", 0.05]]
    assert answer["stages"] == STAGES
    lines = get(server, query + "&format=csv").decode().splitlines()
    assert lines == ["t,device,region,activity,state,kinetics_tau_s,kinetics_rate_hz,kinetics_status,kinetics_bound_s",
                     f"{NOW},cam1,plate,,drying,0.5,2.0,ok,", f"{NOW + 1},cam1,plate,,drying,,,below,0.05"]
    assert b"edgedsmKinetics" in get(server, "/static/kinetics.js")
    assert b"/static/kinetics.js" in get(server, "/")


def test_the_stages_come_from_the_daemon_config_with_kinetics_on(tmp_path: Path) -> None:
    regions = '[[regions]]\nname = "plate"\nwet_above = 0.3\ndry_below = 0.1\n'
    stages = ('[[kinetics.stages]]\nname = "set_to_touch"\nrate_below_hz = 2\n'
              '[[kinetics.stages]]\nname = "tack_free"\nrate_below_hz = 0.2\n')
    on = tmp_path / "on.toml"
    on.write_text(f'[device]\nname = "on"\n{regions}[kinetics]\nenabled = true\n{stages}')
    off = tmp_path / "off.toml"
    off.write_text(f'[device]\nname = "off"\n{regions}[kinetics]\nenabled = false\n{stages}')
    found = regions_from_configs([on, off])
    assert found["on"]["plate"].stages == STAGES
    assert found["off"]["plate"].stages == []  # stages of a daemon that measures no kinetics are never reached
