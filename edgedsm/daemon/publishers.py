"""Publishers that are not MQTT: a logging one (no broker configured) and a recorder (tests)."""

from __future__ import annotations

import json
import logging
import threading
from typing import Any

import numpy as np

log = logging.getLogger("edgedsm.publish")


class LogPublisher:
    """Writes states and alerts to the log; stats at debug level, maps are not kept."""

    def publish_state(self, state: dict[str, Any]) -> None:
        log.info("state %s", json.dumps(state, default=str))

    def publish_alert(self, alert: dict[str, Any]) -> None:
        log.warning("alert %s", json.dumps(alert, default=str))

    def publish_stats(self, stats: dict[str, Any]) -> None:
        log.debug("stats %s", json.dumps(stats, default=str))

    def publish_map(self, name: str, values: np.ndarray, meta: dict[str, Any]) -> None:
        log.debug("map %s %s", name, values.shape)

    def close(self, timeout: float | None = None) -> None:
        return None


class RecordingPublisher:
    """Keeps everything published, for tests and for the in-process demo."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.states: list[dict[str, Any]] = []
        self.alerts: list[dict[str, Any]] = []
        self.stats: list[dict[str, Any]] = []
        self.maps: list[tuple[str, np.ndarray, dict[str, Any]]] = []

    def publish_state(self, state: dict[str, Any]) -> None:
        with self._lock:
            self.states.append(state)

    def publish_alert(self, alert: dict[str, Any]) -> None:
        with self._lock:
            self.alerts.append(alert)

    def publish_stats(self, stats: dict[str, Any]) -> None:
        with self._lock:
            self.stats.append(stats)

    def publish_map(self, name: str, values: np.ndarray, meta: dict[str, Any]) -> None:
        with self._lock:
            self.maps.append((name, values.copy(), meta))

    def close(self, timeout: float | None = None) -> None:
        return None
