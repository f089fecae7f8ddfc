"""What the dashboard costs at plant scale: ``edgedsm bench dashboard`` (docs/scaling.md).

Starts a private mosquitto, ``edgedsm dashboard`` as its own process with one page attached
(an SSE reader, as a browser would hold), and a load generator publishing for N simulated
devices at R updates per second what a daemon publishes: statistics (3 regions x 3 maps), the
state on every transition, an alert on every transition, and a 128² map pair every 10 s.
Prints one table row per device count: messages and bytes per second on the broker, the
dashboard's CPU (user + system, % of one core, from /proc), events pushed to the page. With
``--browser`` the page is also opened in Debian's chromium (headless, through Selenium and
chromium-driver) and its responsiveness measured: the longest delay of a 50 ms timer (how long
the page could not react to a click) and the number of tasks over 50 ms.

Examples:
  edgedsm bench dashboard --devices 1 16 64 --seconds 30 --browser -o docs/scaling-dashboard.md
  edgedsm bench dashboard --devices 4 --seconds 5 --warmup 1      # a quick look
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import threading
import time
import urllib.request

import numpy as np
import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from edgedsm.localbroker import LocalBroker
from edgedsm.messages import Alert, AlertKind, MapStats, RegionState, StateReport, Stats
from edgedsm.publish.mapcodec import encode_map
from edgedsm_lab.bench.report import Report, add_output_argument, load_average

HELP = "the dashboard under N devices' traffic: its CPU, the broker's load, the page's responsiveness"

REGIONS = ("left", "middle", "right")
STATES = ("wet", "drying", "dry")


def _cpu_seconds(pid: int) -> float:
    with open(f"/proc/{pid}/stat", encoding="ascii") as stat:
        fields = stat.read().rpartition(")")[2].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _stats(t: float, activity: float, states: dict[str, str]) -> bytes:
    regions = {name: {key: MapStats(pixels=9800, mean=activity * scale, std=0.04, p05=0.1, median=activity, p95=0.4)
                      for key, scale in (("s1", 80.0), ("s2", 1.0), ("s3", 3.0))} for name in REGIONS}
    return Stats(t=t, frames=int(t) % 100000, ready=True, fps=30.0, laser="on", estimator="s2",
                 drops={"dropped_queue": 0, "dropped_invalid": 0}, camera={"delivered": 5231}, ambient_level=3.2,
                 regions=regions, states=states).to_bytes()


class Load:
    """Publishes for ``devices`` devices at ``rate`` updates/s until stopped; counts what it sent."""

    def __init__(self, port: int, devices: int, rate: float) -> None:
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="edgedsm-loadbench")
        self.client.connect("127.0.0.1", port)
        self.client.loop_start()
        self.devices, self.rate = devices, rate
        self.messages = self.bytes = 0
        self.stop = threading.Event()
        values = np.random.default_rng(1).random((128, 128))
        self.map_png, self.map_meta = encode_map(values, estimator="s2", seq=1, t=time.time(), window=100, lag=5)
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _send(self, topic: str, payload: bytes, qos: int = 0, retain: bool = False) -> None:
        self.client.publish(topic, payload, qos=qos, retain=retain)
        self.messages += 1
        self.bytes += len(payload) + len(topic)

    def _run(self) -> None:
        for device in range(self.devices):
            self._send(f"edgedsm/load{device:02d}/availability", b"online", 1, True)
        tick = 0
        start = time.monotonic()
        while not self.stop.is_set():
            now = time.time()
            for device in range(self.devices):
                base = f"edgedsm/load{device:02d}"
                phase = (tick + device) % 60
                state = STATES[min(2, phase // 20)]
                self._send(f"{base}/stats", _stats(now, 0.4 - phase * 0.005, dict.fromkeys(REGIONS, state)))
                if phase % 20 == 0:
                    report = StateReport(t=now, estimator="s2", laser="on", regions={
                        name: RegionState(region=name, state=state, since=now, activity=0.3) for name in REGIONS})
                    self._send(f"{base}/state", report.to_bytes(), 0, True)
                    alert = Alert(kind=AlertKind.TRANSITION, t=now, region="left", to_state=state, seq=tick + 1,
                                  stream=f"s{device}")
                    self._send(f"{base}/alerts", alert.to_bytes(), 1)
                if phase % 10 == 0:
                    self._send(f"{base}/map/s2/meta", json.dumps(self.map_meta).encode())
                    self._send(f"{base}/map/s2", self.map_png)
            tick += 1
            self.stop.wait(max(0.0, start + tick / self.rate - time.monotonic()))

    def close(self) -> None:
        self.stop.set()
        self.thread.join(5)
        self.client.loop_stop()
        self.client.disconnect()


def _page(url: str, counter: list[int], stop: threading.Event) -> None:
    """An open page: reads the event stream, counting events."""
    with urllib.request.urlopen(url + "api/events", timeout=30) as stream:
        for line in stream:
            if line.startswith(b"event:"):
                counter[0] += 1
            if stop.is_set():
                return


LAG_PROBE = """
window.__lag = {max: 0, long: 0};
let last = performance.now();
setInterval(() => { const now = performance.now(); window.__lag.max = Math.max(window.__lag.max, now - last - 50);
  last = now; }, 50);
new PerformanceObserver((list) => { window.__lag.long += list.getEntries().length; }).observe({type: "longtask"});
"""


def _browser(url: str, profile: str):  # -> selenium WebDriver
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = "/usr/bin/chromium"
    for flag in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--window-size=1400,1200", f"--user-data-dir={profile}"):
        options.add_argument(flag)
    browser = webdriver.Chrome(options=options, service=Service(executable_path="/usr/bin/chromedriver"))
    browser.get(url)
    return browser


def measure(devices: int, rate: float, seconds: float, warmup: float, tmp: str,
            browser: bool = False) -> dict[str, float]:
    with LocalBroker() as broker:
        env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [os.getcwd(), os.environ.get("PYTHONPATH")]))}
        dashboard = subprocess.Popen([sys.executable, "-m", "edgedsm", "dashboard", "--broker",
                                      f"127.0.0.1:{broker.port}", "--listen", "127.0.0.1:0", "--database",
                                      f"{tmp}/bench-{devices}.sqlite3"], stdout=subprocess.PIPE, text=True, env=env)
        try:
            assert dashboard.stdout is not None
            url = dashboard.stdout.readline().split()[2]
            events, stop = [0], threading.Event()
            threading.Thread(target=_page, args=(url, events, stop), daemon=True).start()
            load = Load(broker.port, devices, rate)
            load.thread.start()
            page = _browser(url, f"{tmp}/bench-profile-{devices}") if browser else None
            time.sleep(warmup)
            if page is not None:
                page.execute_script(LAG_PROBE)
            cpu0, t0, m0, b0, e0 = _cpu_seconds(dashboard.pid), time.monotonic(), load.messages, load.bytes, events[0]
            time.sleep(seconds)
            cpu1, t1, m1, b1, e1 = _cpu_seconds(dashboard.pid), time.monotonic(), load.messages, load.bytes, events[0]
            lag = page.execute_script("return window.__lag") if page is not None else {"max": math.nan, "long": 0}
            if page is not None:
                page.quit()
            load.close()
            stop.set()
        finally:
            dashboard.terminate()
            dashboard.wait(10)
            if dashboard.stdout is not None:
                dashboard.stdout.close()
    elapsed = t1 - t0
    return {"devices": devices, "rate": rate, "msg_s": (m1 - m0) / elapsed, "kb_s": (b1 - b0) / elapsed / 1024,
            "cpu": 100 * (cpu1 - cpu0) / elapsed, "events_s": (e1 - e0) / elapsed, "lag_ms": lag["max"],
            "long_tasks": lag["long"]}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--devices", type=int, nargs="+", default=[1, 16, 64], help="device counts, one row each")
    parser.add_argument("--rate", type=float, default=1.0, help="updates per second per device")
    parser.add_argument("--seconds", type=float, default=30.0, help="measured time per row")
    parser.add_argument("--warmup", type=float, default=5.0, help="seconds before each measurement")
    parser.add_argument("--tmp", default="/tmp", help="directory for the dashboards' databases and the browser profile")
    parser.add_argument("--browser", action="store_true", help="also measure the page in chromium (headless)")
    add_output_argument(parser, "the table in docs/scaling.md")


def run(args: argparse.Namespace) -> int:
    load = load_average()
    rows = []
    for count in args.devices:
        row = measure(count, args.rate, args.seconds, args.warmup, args.tmp, args.browser)
        print(f"bench dashboard: {count} devices: {row['cpu']:.1f} % of a core", file=sys.stderr, flush=True)
        page = [f"{row['lag_ms']:.0f} ms", str(row["long_tasks"])] if args.browser else []
        rows.append([str(row["devices"]), f"{row['rate']:.1f}", f"{row['msg_s']:.1f}", f"{row['kb_s']:.1f}",
                     f"{row['cpu']:.1f} %", f"{row['events_s']:.1f}", *page])
    report = Report("The dashboard at plant scale")
    report.line(report.machine(f"edgedsm bench dashboard --devices {' '.join(map(str, args.devices))}", load=load)
                + f" {args.seconds:g} s measured per row after {args.warmup:g} s of warm-up.")
    report.line()
    header = ["devices", "updates/s each", "messages/s", "KiB/s on the broker", "dashboard CPU (% of one core)",
              "events/s to the page"]
    report.table(header + (["page: longest timer delay", "page: tasks > 50 ms"] if args.browser else []), rows,
                 align="r" * (len(header) + (2 if args.browser else 0)))
    if args.output:
        report.save(args.output)
    return 0
