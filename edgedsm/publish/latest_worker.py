"""One worker thread that handles the latest job per key: a newer job replaces one not yet taken.

Maps are large and come on a cadence; when a link or a renderer is slower than the cadence, the
stale map is worth nothing, so it is replaced, never queued (the memory held stays one job per
key). Used by the MQTT map sender and the Home Assistant colour maps.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Generic, TypeVar

from edgedsm.priority import lower_priority

log = logging.getLogger(__name__)

Job = TypeVar("Job")

#: How often an idle worker looks at its stop flag (s).
WORKER_POLL_S = 0.25
#: Niceness of the worker's thread (edgedsm.priority): a map on a 10 s cadence can wait for the
#: engine's kernel threads (encoding one 4096×2168 map takes ~20 ms of CPU).
WORKER_NICE = 10


class LatestWorker(Generic[Job]):
    """Runs ``handle(key, job)`` on its own thread for the latest job of each key, the keys in
    turn (a replaced job keeps its key's place, so no key starves another). ``handle`` raising
    is logged (``what`` names it) and reported to ``on_error``; the worker goes on with the
    next job."""

    def __init__(self, name: str, what: str, handle: Callable[[str, Job], None],
                 on_error: Callable[[str], None] | None = None) -> None:
        self.what = what
        self._handle = handle
        self._on_error = on_error
        self._lock = threading.Lock()
        self._jobs: dict[str, Job] = {}
        self._busy = False  # the worker holds a job it has taken off _jobs
        self._wake = threading.Event()
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._work, name=name, daemon=True)

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    def start(self) -> None:
        self.thread.start()

    def stop(self, timeout_s: float = 0.0) -> None:
        """Stop after the job in hand (waits at most ``timeout_s`` for it)."""
        self._stop.set()
        self._wake.set()
        if timeout_s > 0 and self.thread.is_alive():
            self.thread.join(timeout=timeout_s)

    def submit(self, key: str, job: Job) -> bool:
        """Hand a job over (returns at once); True if it replaced one of the same key not yet taken."""
        with self._lock:
            # a replaced job keeps its key's place in the line: re-queued at the end, a key
            # replaced faster than the worker takes it would go first every time and starve
            # the others
            replaced = key in self._jobs
            self._jobs[key] = job
        self._wake.set()
        return replaced

    def flush(self, timeout_s: float) -> bool:
        """Wait at most ``timeout_s`` until every job handed over has been handled."""
        deadline = time.monotonic() + timeout_s
        while True:
            with self._lock:
                if not self._jobs and not self._busy:
                    return True
            if time.monotonic() >= deadline:
                return False
            self._wake.set()
            time.sleep(0.02)

    def _work(self) -> None:
        lower_priority(WORKER_NICE)
        while not self._stop.is_set():
            self._wake.wait(WORKER_POLL_S)
            self._wake.clear()
            while not self._stop.is_set():
                with self._lock:
                    if not self._jobs:
                        break
                    key = next(iter(self._jobs))
                    job = self._jobs.pop(key)
                    self._busy = True
                try:
                    self._handle(key, job)
                except Exception:  # keep the worker alive for the next jobs
                    log.exception("%s %r failed", self.what, key)
                    if self._on_error is not None:
                        self._on_error(key)
                finally:
                    # let go of the job now, not when the next one comes: a map is tens of MB, and
                    # the daemon reuses its arrays once nobody holds them (snapshot.MapBuffers)
                    del job
                    with self._lock:
                        self._busy = False
