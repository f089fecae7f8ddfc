"""Thread-safe counters of the MQTT link (published under ``mqtt`` in the stats)."""

from __future__ import annotations

import threading

COUNTER_NAMES = ("alerts_sent", "alerts_acked", "alerts_refused", "stats_dropped",
                 "maps_sent", "maps_dropped", "commands", "commands_refused", "storage_faults",
                 "alerts_memory_dropped")


class Counters:
    """Named integer counters; every collaborator of the link adds to the same set."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._counts = dict.fromkeys(COUNTER_NAMES, 0)

    def add(self, name: str, amount: int = 1) -> None:
        with self._lock:
            self._counts[name] += amount

    def snapshot(self) -> dict[str, int]:
        with self._lock:
            return dict(self._counts)
