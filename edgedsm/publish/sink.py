"""The sink contract: where the daemon's typed messages (``edgedsm.messages``) go.

The pipeline hands every message to one :class:`Sink` — in the daemon a :class:`FanOut` over the
configured sinks (MQTT JSON first; Sparkplug B, Home Assistant, Prometheus beside it). A new
sink implements this protocol and is added to the list in ``edgedsm.daemon``; the pipeline does
not change.

Rules every sink keeps:

- ``publish_*`` return quickly (never wait on the network); they are called from the daemon's
  evaluator thread, one call at a time.
- ``publish_alert`` must not lose an alert it accepted (a durable sink stores it first); an
  alert it cannot take raises ``PublishError``.
- Maps are read after the call returns: sinks must not modify ``MapFrame.values``.
- ``flush`` and ``close`` are bounded by their timeout.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable
from typing import Protocol, runtime_checkable

from edgedsm.messages import Alert, AlertKind, LaserState, MapFrame, StateReport, Stats

log = logging.getLogger(__name__)


@runtime_checkable
class Sink(Protocol):
    """One destination of the daemon's messages (see the module docstring)."""

    def publish_state(self, report: StateReport) -> None:
        """Every region's state; called at start, on every transition and after a reset."""

    def publish_alert(self, alert: Alert) -> None:
        """One alert (transition, reset, fault, warning), to be delivered at least once."""

    def publish_stats(self, stats: Stats) -> None:
        """Periodic statistics."""

    def publish_map(self, frame: MapFrame) -> None:
        """One activity map (on the maps cadence, on request, and at the end of a stream)."""

    def flush(self, timeout_s: float) -> bool:
        """Wait (bounded) until everything handed over has left; True if it has."""

    def close(self, timeout_s: float) -> None:
        """Release connections and threads, within ``timeout_s``."""


class FanOut:
    """Hands each message to several sinks; one failing sink neither stops nor delays the others.

    An alert that a sink refuses is re-raised after every sink had its turn, so the caller knows
    it may be lost there (the durable MQTT sink raises only when it cannot store it).
    """

    def __init__(self, sinks: Iterable[Sink]) -> None:
        self.sinks: list[Sink] = list(sinks)

    def _each(self, what: str, call: Callable[[Sink], None]) -> BaseException | None:
        first: BaseException | None = None
        for sink in self.sinks:
            try:
                call(sink)
            except Exception as exc:  # a sink's failure must not take the others down
                log.error("%s: %s failed: %s", type(sink).__name__, what, exc)
                first = first or exc
        return first

    def publish_state(self, report: StateReport) -> None:
        self._each("state", lambda sink: sink.publish_state(report))

    def publish_alert(self, alert: Alert) -> None:
        error = self._each("alert", lambda sink: sink.publish_alert(alert))
        if error is not None:
            raise error

    def publish_stats(self, stats: Stats) -> None:
        self._each("stats", lambda sink: sink.publish_stats(stats))

    def publish_map(self, frame: MapFrame) -> None:
        self._each("map", lambda sink: sink.publish_map(frame))

    def stopping(self, laser: LaserState) -> None:
        """The daemon stops, the laser as confirmed (``off``; ``unknown`` when the relay did not
        confirm): each sink with a ``stopping(laser, t)`` says so before :meth:`close` (the MQTT
        JSON sink's retained state; the others' ``offline``, NDEATH or server end say enough)."""
        now = time.time()

        def stop(sink: Sink) -> None:
            stopping = getattr(sink, "stopping", None)
            if stopping is not None:
                stopping(laser, now)

        self._each("stop", stop)

    def flush(self, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        return all([sink.flush(max(0.0, deadline - time.monotonic())) for sink in self.sinks])

    def close(self, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        for sink in self.sinks:
            try:
                sink.close(max(0.0, deadline - time.monotonic()))
            except Exception as exc:
                log.error("%s: close failed: %s", type(sink).__name__, exc)


class LogSink:
    """Writes states and alerts to the log (no broker configured); stats at debug level."""

    def publish_state(self, report: StateReport) -> None:
        states = ", ".join(f"{name} {region.state}" for name, region in report.regions.items())
        log.info("state: %s (laser %s)", states, report.laser)

    def publish_alert(self, alert: Alert) -> None:
        # a fault or a warning is an alert (WARNING); a normal transition or a reset is news (INFO)
        serious = alert.kind in (AlertKind.FAULT, AlertKind.WARNING) or alert.to_state == "fault"
        log.log(logging.WARNING if serious else logging.INFO, "alert: %s", alert.describe())

    def publish_stats(self, stats: Stats) -> None:
        if log.isEnabledFor(logging.DEBUG):
            log.debug("stats %s", stats.to_bytes().decode())

    def publish_map(self, frame: MapFrame) -> None:
        log.debug("map %s %s at frame %d", frame.name, frame.values.shape, frame.seq)

    def flush(self, timeout_s: float) -> bool:
        return True

    def close(self, timeout_s: float) -> None:
        return None


class RecordingSink:
    """Keeps every message, for tests and the in-process demo (thread-safe)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.states: list[StateReport] = []
        self.alerts: list[Alert] = []
        self.stats: list[Stats] = []
        self.maps: list[MapFrame] = []

    def publish_state(self, report: StateReport) -> None:
        with self._lock:
            self.states.append(report)

    def publish_alert(self, alert: Alert) -> None:
        with self._lock:
            self.alerts.append(alert)

    def publish_stats(self, stats: Stats) -> None:
        with self._lock:
            self.stats.append(stats)

    def publish_map(self, frame: MapFrame) -> None:
        with self._lock:
            self.maps.append(frame)

    def flush(self, timeout_s: float) -> bool:
        return True

    def close(self, timeout_s: float) -> None:
        return None
