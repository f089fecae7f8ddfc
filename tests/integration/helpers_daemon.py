"""The daemon as a real process: config files in TOML and `python -m edgedsm run -c CONFIG` with its
log collected line by line (used by test_aravis.py and tests/faults).
"""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from helpers_mqtt import child_env

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


def write_config(path: Path, config: dict[str, Any]) -> Path:
    """Write atomically (a SIGHUP must never see half a file)."""
    partial = path.with_name(path.name + ".partial")
    partial.write_text(toml_text(config), encoding="utf-8")
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
