"""The service shell around the pipeline: devices from the config, laser safety, signals,
systemd notification and watchdog, configuration reload.

- SIGTERM / SIGINT: stop; the laser is switched off, ``offline`` published, exit 0 (within 2 s).
  If the laser could not be confirmed off: logged CRITICAL, a ``fault`` alert published before
  ``offline``, exit 69 (``EX_UNAVAILABLE``: the relay is not answering).
- SIGHUP: reload the config file, transactionally (``edgedsm.daemon.reload``): the new one is
  checked completely first (file, camera, regions inside its frame, relay); if anything is
  wrong the reason is logged and published as a warning alert and the daemon keeps running
  with the old one. A good one that changes only publishing, logging or thresholds is applied
  to the running measurement (sessions, window and states kept; changed sinks rebuilt); one
  that changes measurement publishes a ``reset`` alert naming what changed and restarts the
  pipeline (``reload.SECTION_CHANGE``; docs/architecture.md, "Reload").
- ``Type=notify``: READY once measuring, STATUS lines, WATCHDOG pings only while frames keep
  arriving (a stalled camera lets systemd's watchdog restart the service).
"""

from __future__ import annotations

import contextlib
import logging
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from types import FrameType
from typing import Any

from edgedsm.config import DaemonConfig, load_config
from edgedsm.daemon.devices import couple_simulated_laser, open_camera_for
from edgedsm.daemon.notify import Notifier
from edgedsm.daemon.pipeline import Cadence, Pipeline
from edgedsm.daemon.reload import ReloadRefused, changed_sections, check_reload, restart_reasons
from edgedsm.daemon.sinks import SinkSet, make_sink  # noqa: F401 (make_sink: the daemon's sinks, for tests)
from edgedsm.devices.laser import LaserSafety, open_relay
from edgedsm.errors import ConfigError, DeviceError
from edgedsm.messages import Alert, AlertKind
from edgedsm.publish.commands import Command, CommandResult
from edgedsm.publish.sink import Sink
from edgedsm.signals import handling

log = logging.getLogger(__name__)

#: Seconds between the STATUS lines `systemctl status` shows.
STATUS_EVERY_S = 10.0

#: How long the end of a finite stream waits for its final maps to be published.
FINAL_MAPS_TIMEOUT_S = 5.0

#: Exit status when the laser could not be confirmed off at stop (sysexits EX_UNAVAILABLE).
EXIT_LASER_NOT_OFF = 69


class Service:
    """Runs pipelines for a config file until stopped (see the module docstring)."""

    def __init__(self, config_path: str | Path | None, config: DaemonConfig | None = None,
                 notifier: Notifier | None = None, cadence: Cadence | None = None) -> None:
        self.config_path = Path(config_path) if config_path is not None else None
        self.config = config if config is not None else load_config(self.config_path)  # type: ignore[arg-type]
        self.notifier = notifier or Notifier()
        self.cadence = cadence
        self._stop = threading.Event()
        self._reload = threading.Event()
        self.pipeline: Pipeline | None = None
        self.exit_reason = ""
        self._reloaded = False
        self._restart_reasons: list[str] = []
        self.sinks = SinkSet(self._on_command)
        self.laser_not_off: str | None = None  # why the laser could not be confirmed off at stop

    # -- signals ----------------------------------------------------------------------------
    @contextlib.contextmanager
    def handling_signals(self) -> Iterator[Service]:
        """SIGTERM/SIGINT stop and SIGHUP reloads while inside; the previous handlers are put
        back on the way out (in-process callers, e.g. tests, keep theirs). Main thread only."""
        with handling({signal.SIGTERM: self._on_stop_signal, signal.SIGINT: self._on_stop_signal,
                       signal.SIGHUP: self._on_reload_signal}):
            yield self

    def _on_stop_signal(self, signum: int, frame: FrameType | None) -> None:
        self.exit_reason = signal.Signals(signum).name
        self._stop.set()

    def _on_reload_signal(self, signum: int, frame: FrameType | None) -> None:
        self._reload.set()

    def stop(self) -> None:
        self._stop.set()

    def request_reload(self) -> None:
        self._reload.set()

    def _should_stop(self) -> bool:
        if self._stop.is_set():
            return True
        if self._reload.is_set():
            self._reload.clear()
            return self._try_reload()
        return False

    def _try_reload(self) -> bool:
        """Check the config file and apply it; True if the pipeline must restart for it."""
        if self.config_path is None:
            log.warning("reload requested but the daemon was not started from a file")
            return False
        self.notifier.reloading()
        pipeline = self.pipeline
        try:
            new = check_reload(self.config_path, self.config, pipeline.frame_shape if pipeline else None)
        except ReloadRefused as exc:
            self._refuse_reload(str(exc))
            return False
        for note in new.notes:
            log.warning("%s", note)
        changed = changed_sections(new, self.config)
        restart = restart_reasons(new, self.config)
        try:
            self.sinks.apply(new)  # sinks whose settings did not change keep their sessions
        except ConfigError as exc:  # e.g. the new [http] port is taken: back to the running sinks
            self.sinks.apply(self.config)  # raises only if the running ones cannot start again either
            self._refuse_reload(f"the new configuration cannot run: {exc}")
            return False
        if "logging" in changed:
            from edgedsm.logs import configure_logging

            configure_logging(new.logging.level, new.logging.json_lines)
        what = ", ".join(changed) or "nothing"
        if restart:
            log.warning("configuration reloaded from %s (changed: %s); measurement restarts for: %s",
                        self.config_path, what, ", ".join(restart))
            self._restart_reasons = restart
            self.config = new
            self._reloaded = True
            return True
        if pipeline is not None:
            pipeline.apply(new, Cadence.of(new.cadence), self.sinks.recorder)
        self.config = new
        log.warning("configuration reloaded from %s (changed: %s); measurement kept", self.config_path, what)
        self.notifier.ready(status=f"measuring with {new.camera.uri} (reloaded)")
        return False

    def _refuse_reload(self, reason: str) -> None:
        log.error("reload refused, keeping the running configuration: %s", reason)
        summary = reason.splitlines()[0].rstrip(":")
        if self.pipeline is not None:
            why = f"reload refused, running configuration kept: {reason}"
            self.pipeline.publish_alert(Alert(kind=AlertKind.WARNING, t=time.time(), reason=why))
        self.notifier.ready(status=f"reload refused: {summary} (see the log)")

    # -- running ----------------------------------------------------------------------------
    def run(self) -> int:
        """Measure until stopped; returns the process exit code."""
        for note in self.config.notes:
            log.warning("%s", note)
        self.sinks.apply(self.config)
        try:
            return self._run_pipelines()
        finally:
            # the retained state's last word: offline, the laser off (or unknown: not confirmed)
            self.sinks.fanout.stopping("unknown" if self.laser_not_off is not None else "off")
            self.sinks.close(1.0)  # 'offline' out within the 2 s a SIGTERM allows

    def _run_pipelines(self) -> int:
        while True:
            if self._reloaded:
                self._announce_reset()
            self._reloaded = False
            try:
                self._run_once()
            except Exception:
                if self.laser_not_off is None:
                    raise
                log.exception("stopped on an error")
            if self.laser_not_off is not None:
                return EXIT_LASER_NOT_OFF
            if self._stop.is_set():
                log.info("stopped (%s)", self.exit_reason or "requested")
                return 0
            if not self._reloaded:
                log.info("camera stream ended")
                return 0

    def _announce_reset(self) -> None:
        """Before the states start again: one ``reset`` alert naming what changed."""
        reason = f"configuration reloaded, measurement restarted: {', '.join(self._restart_reasons)} changed"
        try:
            self.sinks.fanout.publish_alert(Alert(kind=AlertKind.RESET, t=time.time(), reason=reason))
        except Exception as exc:  # logged by the fan-out; the log line below stands
            log.error("the reset alert could not be handed over: %s", exc)
        log.warning("%s; every region warms up again", reason)

    def _on_command(self, name: str, command: Command) -> dict[str, Any]:
        # called on the MQTT sink's command thread with a validated command
        pipeline = self.pipeline
        result = pipeline.submit(command) if pipeline is not None else CommandResult.refused("not running")
        return result.as_mapping()

    def _run_once(self) -> None:
        config = self.config
        camera = open_camera_for(config)  # touches no device until the pipeline opens it
        holder: dict[str, Pipeline] = {}
        last_ping = [0.0, 0.0]  # watchdog, status

        def alive() -> None:
            # called by the pipeline thread while frames keep arriving
            now = time.monotonic()
            interval = self.notifier.watchdog_s
            if interval and now - last_ping[0] >= interval:
                last_ping[0] = now
                self.notifier.watchdog()
            pipeline = holder.get("pipeline")
            if self.notifier.enabled and pipeline is not None and now - last_ping[1] >= STATUS_EVERY_S:
                last_ping[1] = now
                self.notifier.status(pipeline.summary())

        sink = self.sinks.fanout
        self.pipeline = None
        # opened last and closed by LaserSafety (switched off) whatever happens after
        relay = open_relay(config.laser.spec) if config.laser is not None else None
        couple_simulated_laser(camera, relay)
        pipeline = Pipeline(config, camera, sink, relay=relay, cadence=self.cadence,
                            on_alive=alive, probes=self.sinks.probes, recorder=self.sinks.recorder)
        holder["pipeline"] = self.pipeline = pipeline
        safety = LaserSafety(relay) if relay is not None else None
        try:
            with safety or contextlib.nullcontext():
                self._measure(pipeline)
        except DeviceError as exc:
            if safety is None or exc is not safety.off_error:
                raise
        finally:
            if safety is not None and safety.off_error is not None:
                self._laser_left_on(sink, safety.off_error)
        # a finite stream (replay) ended: its final maps must leave before the sink closes,
        # which abandons maps still waiting to be sent
        if not self._stop.is_set() and not self._reloaded and not sink.flush(FINAL_MAPS_TIMEOUT_S):
            log.warning("the final maps were not all published within %.1f s", FINAL_MAPS_TIMEOUT_S)

    def _laser_left_on(self, sink: Sink, error: DeviceError) -> None:
        """The laser may still be on: say so everywhere before 'offline' goes out."""
        self.laser_not_off = str(error)
        log.critical("THE LASER COULD NOT BE SWITCHED OFF and may still be on: %s", error)
        self.notifier.status(f"laser NOT confirmed off: {error}")
        try:
            reason = f"the laser could not be switched off at stop and may still be on: {error}"
            sink.publish_alert(Alert(kind=AlertKind.FAULT, t=time.time(), reason=reason))
        except Exception as exc:  # the log line above stands
            log.error("the fault alert could not be handed over: %s", exc)

    def _measure(self, pipeline: Pipeline) -> None:
        self.notifier.ready(status=f"measuring with {self.config.camera.uri}")
        pipeline.run(self._should_stop)
        if self._stop.is_set():
            self.notifier.stopping()

