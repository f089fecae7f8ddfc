"""Alerts kept until acknowledged: on disk (:class:`AlertQueue`) while the disk takes writes, in
memory (bounded) while it refuses them, and never a crash.

When a write fails (disk full, file system read-only) the store turns *degraded*: a ``fault``
alert ``storage: <the disk's own words>`` is added (once per episode), and this alert and the
next ones get their ``seq`` here (continuing the disk's numbering) and wait in memory, still
published. Every ``RETRY_S`` the memory-held alerts are written back in one transaction, with
their seq kept and the disk's numbering moved past them; after that the store writes to disk
again. Alerts held in memory are lost if the daemon dies before the disk recovers (at most
``MEMORY_MAX`` of them, the oldest dropped first and counted).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

from edgedsm.messages import Alert, AlertKind
from edgedsm.publish.alertqueue import AlertQueue, QueuedAlert
from edgedsm.publish.counters import Counters
from edgedsm.publish.errors import StorageError

log = logging.getLogger(__name__)

MEMORY_MAX = 2000  # alerts held in memory while the disk refuses writes
RETRY_S = 2.0      # how often a degraded store tries the disk again


class AlertStore:
    """Thread-safe; the same ``put``/``pending``/``ack`` as :class:`AlertQueue`, never failing
    for a storage reason."""

    def __init__(self, queue: AlertQueue, counters: Counters, *, memory_max: int = MEMORY_MAX,
                 retry_s: float = RETRY_S, clock: Callable[[], float] = time.monotonic) -> None:
        self.queue = queue
        self._counters = counters
        self._memory_max = memory_max
        self._retry_s = retry_s
        self._clock = clock
        self._lock = threading.Lock()
        self._memory: dict[int, QueuedAlert] = {}  # seq -> alert, in seq order (insertion order)
        self._unremoved: set[int] = set()          # acknowledged, but the disk refused the delete
        self._last_seq = 0                          # highest seq given out while degraded
        self._fault: str | None = None
        self._next_retry = 0.0

    @property
    def stream(self) -> str:
        return self.queue.stream

    @property
    def fault(self) -> str | None:
        """The disk's refusal while degraded (``None`` when alerts go to disk)."""
        return self._fault

    @property
    def in_memory(self) -> int:
        with self._lock:
            return len(self._memory)

    def __len__(self) -> int:
        with self._lock:
            return len(self.queue) - len(self._unremoved) + len(self._memory)

    def put(self, alert: Mapping[str, Any]) -> QueuedAlert:
        """Keep an alert and give it its seq; PublishError only for an alert that is not JSON
        or too big (a bug upstream), never for the disk."""
        with self._lock:
            if self._fault is None:
                try:
                    return self.queue.put(alert)
                except StorageError as exc:
                    self._degrade(exc)
            return self._hold(alert)

    def pending(self, after_seq: int = 0, limit: int = 100) -> list[QueuedAlert]:
        """Unacknowledged alerts with ``seq > after_seq``, oldest first, at most ``limit``."""
        with self._lock:
            held = [item for seq, item in self._memory.items() if seq > after_seq][:limit]
            skip = set(self._unremoved)
        stored = [item for item in self.queue.pending(after_seq, limit + len(skip)) if item.seq not in skip]
        return sorted(stored + held, key=lambda item: item.seq)[:limit]

    def ack(self, seq: int) -> None:
        """The broker has the alert: forget it."""
        with self._lock:
            if self._memory.pop(seq, None) is not None:
                return
            try:
                self.queue.ack(seq)
            except StorageError as exc:
                self._unremoved.add(seq)
                if self._fault is None:
                    self._degrade(exc)

    def retry(self) -> bool:
        """Write memory-held alerts back when it is time to try; True once the disk took them."""
        with self._lock:
            if self._fault is None:
                return True
            if self._clock() < self._next_retry:
                return False
            self._next_retry = self._clock() + self._retry_s
            try:
                self.queue.restore(list(self._memory.values()), self._last_seq)
                for seq in sorted(self._unremoved):
                    self.queue.ack(seq)
                    self._unremoved.discard(seq)
            except StorageError as exc:
                log.debug("storage still refuses writes: %s", exc)
                return False
            log.warning("storage: %s takes writes again; %d alert(s) held in memory written back",
                        self.queue.path.parent, len(self._memory))
            self._memory.clear()
            self._fault = None
            return True

    # -- private (lock held) --------------------------------------------------------------------

    def _degrade(self, exc: StorageError) -> None:
        """Switch to memory and report the fault (as an alert of its own, held with the others)."""
        cause = str(exc)
        self._fault = cause
        self._last_seq = max(self._last_seq, self.queue.last_seq)
        self._next_retry = self._clock() + self._retry_s
        self._counters.add("storage_faults")
        log.error("storage: %s; alerts are kept in memory (at most %d) until it takes writes again",
                  cause, self._memory_max)
        self._hold(Alert(kind=AlertKind.FAULT, t=time.time(), reason=f"storage: {cause}").to_json())

    def _hold(self, alert: Mapping[str, Any]) -> QueuedAlert:
        """Number the alert (after the disk's numbering) and keep it in memory, bounded."""
        payload = self.queue.encode(alert, self._last_seq + 1)  # a bad alert raises before taking a seq
        self._last_seq += 1
        item = QueuedAlert(self._last_seq, payload)
        self._memory[item.seq] = item
        while len(self._memory) > self._memory_max:
            dropped = next(iter(self._memory))
            del self._memory[dropped]
            self._counters.add("alerts_memory_dropped")
            log.error("storage: %d alerts held in memory: dropped the oldest (seq %d)", self._memory_max, dropped)
        return item
