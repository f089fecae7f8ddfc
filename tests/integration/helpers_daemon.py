"""The daemon as a real process: config files in TOML and `python -m edgedsm run -c CONFIG` with its
log collected line by line (used by test_aravis.py and tests/faults).
"""

from __future__ import annotations

import contextlib
import http.client
import itertools
import json
import re
import signal
import subprocess
import sys
import threading
import time
import tomllib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from helpers_mqtt import REPO, WAIT_S, Received, Subscriber, child_env, wait_until

from edgedsm.daemon.service import Service
from edgedsm.publish import Topics

LOG_TAIL_LINES = 40


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str | Path):
        return json.dumps(str(value))  # a JSON string is a valid TOML basic string
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(item) for item in value) + "]"
    raise TypeError(f"no TOML for {value!r}")


def toml_text(config: dict[str, Any]) -> str:
    """TOML for a dict of tables (dicts) and arrays of tables (lists of dicts) of scalars."""
    lines: list[str] = []
    for name, table in config.items():
        for body, header in ([(table, f"[{name}]")] if isinstance(table, dict)
                             else [(item, f"[[{name}]]") for item in table]):
            lines.append(header)
            lines += [f"{key} = {_toml_value(value)}" for key, value in body.items()]
            lines.append("")
    return "\n".join(lines)


def write_config(path: Path, config: dict[str, Any] | str) -> Path:
    """Write atomically (a SIGHUP must never see half a file); ``config`` a dict of tables or TOML text."""
    text = config if isinstance(config, str) else toml_text(config)
    partial = path.with_name(path.name + ".partial")
    partial.write_text(text, encoding="utf-8")
    partial.replace(path)
    return path


class Daemon:
    """`python -m edgedsm run -c CONFIG`; its log (stderr) is collected line by line."""

    def __init__(self, config: Path, env: dict[str, str] | None = None) -> None:
        base = {k: v for k, v in child_env().items() if not k.startswith(("NOTIFY_SOCKET", "WATCHDOG_"))}
        self.started = time.monotonic()
        self.process = subprocess.Popen([sys.executable, "-m", "edgedsm", "run", "-c", str(config)],
                                        stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                        stderr=subprocess.PIPE, text=True, env={**base, **(env or {})})
        self.lines: list[tuple[float, str]] = []  # (time.monotonic() on arrival, line)
        self._lock = threading.Lock()
        self._reader = threading.Thread(target=self._read, daemon=True, name="daemon-stderr")
        self._reader.start()

    def _read(self) -> None:
        assert self.process.stderr is not None
        for line in self.process.stderr:
            with self._lock:
                self.lines.append((time.monotonic(), line.rstrip("\n")))

    @property
    def log(self) -> str:
        with self._lock:
            return "\n".join(line for _, line in self.lines)

    def matching(self, pattern: str) -> list[tuple[float, str]]:
        """Log lines matching ``pattern``, with their arrival times (monotonic)."""
        regex = re.compile(pattern)
        with self._lock:
            return [(t, line) for t, line in self.lines if regex.search(line)]

    def wait_log(self, pattern: str, timeout: float, after: float = -1.0) -> float:
        """Wait for a log line matching ``pattern`` that arrived after ``after``; returns its arrival."""
        deadline = time.monotonic() + timeout
        while True:
            found = [t for t, _ in self.matching(pattern) if t > after]
            if found:
                return found[0]
            if self.process.poll() is not None:
                self._reader.join(2)
                pytest.fail(f"the daemon exited ({self.process.returncode}) before logging {pattern!r}:\n{self.log}")
            if time.monotonic() > deadline:
                pytest.fail(f"the daemon did not log {pattern!r} within {timeout} s:\n{self.log}")
            time.sleep(0.02)

    def wait_until(self, predicate: Callable[[], bool], timeout: float, what: str) -> None:
        """Wait (bounded) for ``predicate``; a failure shows the end of the daemon's log."""
        deadline = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() > deadline:
                tail = "\n".join(self.log.splitlines()[-LOG_TAIL_LINES:])
                pytest.fail(f"timed out after {timeout} s waiting for {what}; the daemon's log ends:\n{tail}")
            time.sleep(0.02)

    def signal(self, signum: int) -> None:
        self.process.send_signal(signum)

    def wait(self, timeout: float) -> int:
        """Wait for the daemon to exit by itself; its exit code."""
        try:
            code = self.process.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.kill()
            pytest.fail(f"the daemon did not exit within {timeout} s:\n{self.log}")
        self._reader.join(2)
        return code

    def terminate(self, timeout: float = 10.0) -> tuple[int, float]:
        """SIGTERM; (exit code, seconds until it exited)."""
        started = time.monotonic()
        self.process.send_signal(signal.SIGTERM)
        try:
            code = self.process.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.kill()
            pytest.fail(f"the daemon did not exit within {timeout} s of SIGTERM:\n{self.log}")
        elapsed = time.monotonic() - started
        self._reader.join(2)
        return code, elapsed

    def kill(self) -> None:
        """SIGKILL (as the OOM killer would) and wait for it."""
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait(timeout=10)
        self._reader.join(2)
        if self.process.stderr is not None:
            self.process.stderr.close()


# -- the demo plate as the daemon's camera ---------------------------------------------------

DRYING_SCENE = REPO / "config" / "scenes" / "drying_demo.toml"
#: The demo config's plate thresholds, judged on S2 above the noise floor (one statement: the
#: shipped demo's, so that a test and a user see the same plate go wet -> drying -> dry).
DEMO_PLATE: dict[str, float] = {key: tomllib.loads((REPO / "config" / "daemon" / "demo.toml").read_text())
                                ["regions"][0][key] for key in ("wet_above", "dry_below")}
#: The demo plate at 100 frames/s instead of 20: wet → drying → dry in about 12 s.
SIM_CAMERA = f"sim:{DRYING_SCENE}?time_scale=0.2"


def base_config(tmp_path: Path, *, device: str = "e2e", camera: str = SIM_CAMERA, port: int | None = None,
                laser: str | None = None, region: str = "plate") -> dict[str, Any]:
    """The demo's daemon config, with quick dwell, quick reconnects and its state in tmp_path."""
    config: dict[str, Any] = {
        "device": {"name": device, "state_dir": tmp_path / "state"},
        "camera": {"uri": camera},
        "acquisition": {"dark_frames": 5 if laser else 0, "dark_every_min": 0},
        "estimator": {"activity": "s2", "window": 100, "lag": 5, "q": 1.0},
        "regions": [{"name": region, **DEMO_PLATE, "hysteresis": 0.05,
                     "min_dwell_s": 1.0}],
        "logging": {"level": "info"},
    }
    if laser is not None:
        config["laser"] = {"uri": laser}
    if port is not None:
        config["mqtt"] = {"host": "127.0.0.1", "port": port, "keepalive_s": 5, "connect_timeout_s": 2.0,
                          "reconnect_min_s": 0.1, "reconnect_max_s": 0.5}
        config["cadence"] = {"stats_interval_s": 0.5, "maps_interval_s": 60.0}
    return config


@contextlib.contextmanager
def service_thread(config: Path) -> Iterator[tuple[Service, dict[str, Any]]]:
    """`Service` of a config file running in a thread; stopped (bounded) on exit."""
    service = Service(config)
    result: dict[str, Any] = {}

    def run() -> None:
        result["code"] = service.run()

    thread = threading.Thread(target=run, name="e2e-service", daemon=True)
    result["thread"] = thread
    thread.start()
    try:
        yield service, result
    finally:
        service.stop()
        thread.join(10)


# -- what a subscriber saw -----------------------------------------------------------------

def distinct_alerts(subscriber: Subscriber, topics: Topics) -> list[dict[str, Any]]:
    """Alerts deduplicated on (stream, seq), in seq order."""
    unique = {(a["stream"], a["seq"]): a for a in subscriber.alerts(topics)}
    return [unique[key] for key in sorted(unique, key=lambda key: key[1])]


def moves(alerts: list[dict[str, Any]]) -> list[tuple[str, str]]:
    return [(a["from"], a["to"]) for a in alerts]


def collapse(values: list[str]) -> list[str]:
    """Consecutive repeats removed."""
    return [value for value, _ in itertools.groupby(values)]


def region_states(messages: list[Received], region: str) -> list[str]:
    return [m.json()["regions"][region]["state"] for m in messages]


def last_stats(subscriber: Subscriber, topics: Topics) -> dict[str, Any] | None:
    stats = subscriber.on(topics.stats)
    return stats[-1].json() if stats else None


def frames_published(subscriber: Subscriber, topics: Topics) -> int:
    stats = last_stats(subscriber, topics)
    return int(stats["frames"]) if stats else -1


def wait_frames_beyond(subscriber: Subscriber, topics: Topics, count: int, timeout: float = WAIT_S) -> int:
    """Wait until a stats message reports more than ``count`` frames; returns its count."""
    wait_until(lambda: frames_published(subscriber, topics) > count, timeout, f"stats with more than {count} frames")
    return frames_published(subscriber, topics)


def http_get(port: int, path: str) -> tuple[int, bytes]:
    """GET ``path`` from a daemon's HTTP server on 127.0.0.1: (status, body)."""
    connection = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
    try:
        connection.request("GET", path)
        response = connection.getresponse()
        return response.status, response.read()
    finally:
        connection.close()
