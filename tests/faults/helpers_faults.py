"""Parts of the fault-injection cases: the plant's view over MQTT, a relay board that records
when the laser really switched, and the daemon's config (fixtures in conftest.py).
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from helpers_mqtt import Subscriber
from helpers_relay import NumatoBoard

from edgedsm.publish import Topics

DEVICE = "faults"
TOPICS = Topics.of("edgedsm", DEVICE)
#: The emulated Numato board switches relay 11 (off the default: a driver ignoring channel= fails).
NUMATO_CHANNEL = 11
MEASURED_STATES = ("wet", "drying", "dry")


class Plant(Subscriber):
    """A SCADA-like subscriber: everything the daemon publishes, alerts deduplicated."""

    def distinct_alerts(self) -> list[dict[str, Any]]:
        """Alerts deduplicated on (stream, seq), in (stream, seq) order."""
        unique = {(a["stream"], a["seq"]): a for a in self.alerts(TOPICS)}
        return [unique[key] for key in sorted(unique)]

    def fault_alerts(self) -> list[dict[str, Any]]:
        """Alerts that report a fault: of type ``fault`` where the daemon has them, else
        transitions of a region into the ``fault`` state."""
        alerts = self.distinct_alerts()
        typed = [a for a in alerts if a.get("type") == "fault"]
        return typed or [a for a in alerts if a.get("to") == "fault"]

    def stats(self) -> list[dict[str, Any]]:
        return [m.json() for m in self.on(TOPICS.stats)]

    def frames(self) -> int:
        stats = self.stats()
        return int(stats[-1]["frames"]) if stats else -1

    def measuring_since(self, frames: int, region: str = "plate") -> bool:
        """A stats message with more than ``frames`` frames and ``region`` in a measured state."""
        return any(s["frames"] > frames and s.get("state", {}).get(region) in MEASURED_STATES
                   for s in self.stats())


class RecordingNumato(NumatoBoard):
    """The emulated Numato board, also recording every switching command and when the contact
    really moved."""

    def __init__(self, path: str, channel: int) -> None:
        super().__init__(path, channel)
        self.commands: list[tuple[float, bool]] = []  # (time.monotonic(), on) of every on/off command
        self.changes: list[tuple[float, bool]] = []   # (time.monotonic(), on) when the contact moved
        self._changes_lock = threading.Lock()

    def switch(self, on: bool) -> None:
        was = self.is_on
        super().switch(on)
        now = time.monotonic()
        with self._changes_lock:
            self.commands.append((now, on))
            if self.is_on != was:
                self.changes.append((now, self.is_on))

    def switched(self, on: bool, after: float) -> float | None:
        """When the contact first moved to ``on`` after ``after`` (monotonic), None if it has not."""
        with self._changes_lock:
            return next((t for t, state in self.changes if state == on and t > after), None)

    def first_command(self, after: float) -> bool | None:
        """The first on/off command after ``after`` (True = on), None if there was none."""
        with self._changes_lock:
            return next((on for t, on in self.commands if t > after), None)

    def on_between(self, start: float, end: float) -> bool:
        """Whether the laser was on at any moment in [start, end]."""
        with self._changes_lock:
            before = [state for t, state in self.changes if t <= start]
            inside = [state for t, state in self.changes if start < t <= end]
        return bool(before and before[-1]) or any(inside)


@dataclass
class RelayRig:
    board: RecordingNumato
    uri: str


def daemon_config(tmp_path: Path, *, camera: str, port: int, laser: str, grab_timeout_s: float = 2.0,
                  frame_interval_s: float | None = None, window: int = 20, lag: int = 2,
                  wet_above: float = 1e6, dry_below: float = 1e5, min_dwell_s: float = 0.0) -> dict[str, Any]:
    """A daemon config with quick reconnects, frequent stats and its state in ``tmp_path``."""
    config: dict[str, Any] = {
        "device": {"name": DEVICE, "state_dir": tmp_path / "state"},
        "camera": {"uri": camera, "grab_timeout_s": grab_timeout_s, "reconnect_initial_s": 0.5,
                   "reconnect_max_s": 2.0},
        "laser": {"uri": laser},
        "acquisition": {"dark_frames": 3, "dark_every_min": 0},
        "estimator": {"activity": "s2", "window": window, "lag": lag, "q": 1.0},
        "regions": [{"name": "plate", "wet_above": wet_above, "dry_below": dry_below, "hysteresis": 0.05,
                     "min_dwell_s": min_dwell_s}],
        "cadence": {"stats_interval_s": 0.5, "maps_interval_s": 600.0},
        "mqtt": {"host": "127.0.0.1", "port": port, "keepalive_s": 5, "connect_timeout_s": 2.0,
                 "reconnect_min_s": 0.1, "reconnect_max_s": 0.5},
        "logging": {"level": "info"},
    }
    if frame_interval_s is not None:
        config["camera"]["frame_interval_s"] = frame_interval_s
    return config
