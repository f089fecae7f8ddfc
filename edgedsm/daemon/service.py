"""The service shell around the pipeline: devices from the config, laser safety, signals,
systemd notification and watchdog, configuration reload.

- SIGTERM / SIGINT: stop; the laser is switched off, ``offline`` published, exit 0 (within 2 s).
  If the laser could not be confirmed off: logged CRITICAL, a ``fault`` alert published before
  ``offline``, exit 69 (``EX_UNAVAILABLE``: the relay is not answering).
- SIGHUP: reload the config file, transactionally (``edgedsm.daemon.reload``): the new one is
  checked completely first (file, camera, regions inside its frame, relay); if anything is
  wrong the reason is logged and published as a warning alert and the daemon keeps running
  with the old one; a good one restarts the pipeline with it.
- ``Type=notify``: READY once measuring, STATUS lines, WATCHDOG pings only while frames keep
  arriving (a stalled camera lets systemd's watchdog restart the service).
"""

from __future__ import annotations

import contextlib
import logging
import signal
import threading
import time
from pathlib import Path
from types import FrameType
from typing import Any

from edgedsm.config import DaemonConfig, load_config
from edgedsm.daemon.notify import Notifier
from edgedsm.daemon.pipeline import Cadence, Pipeline
from edgedsm.daemon.probes import PipelineProbes
from edgedsm.daemon.reload import ReloadRefused, check_reload
from edgedsm.devices.camera.base import Camera
from edgedsm.devices.camera.sim import SimulatedCamera
from edgedsm.devices.camera.uri import open_camera
from edgedsm.devices.laser import LaserRelay, LaserSafety, SimulatedRelay, open_relay
from edgedsm.errors import ConfigError, DeviceError
from edgedsm.estimators import ESTIMATORS
from edgedsm.messages import Alert, AlertKind
from edgedsm.publish.command_channel import CommandHandler
from edgedsm.publish.commands import Command
from edgedsm.publish.sink import FanOut, LogSink, Sink

log = logging.getLogger(__name__)

#: Seconds between the STATUS lines `systemctl status` shows.
STATUS_EVERY_S = 10.0

#: How long the end of a finite stream waits for its final maps to be published.
FINAL_MAPS_TIMEOUT_S = 5.0

#: Exit status when the laser could not be confirmed off at stop (sysexits EX_UNAVAILABLE).
EXIT_LASER_NOT_OFF = 69


def open_camera_for(config: DaemonConfig) -> Camera:
    """The configured camera, built from the spec the config parsed (paths already resolved)."""
    return open_camera(config.camera.spec)


def make_sink(config: DaemonConfig, on_command: CommandHandler) -> tuple[Sink, PipelineProbes]:
    """Where the pipeline's messages go — every configured sink (MQTT JSON when ``[mqtt]`` is set,
    Home Assistant, Prometheus), the log when no broker is — and the probes those sinks measure
    the pipeline with. A new sink is added here; the pipeline does not change."""
    sinks: list[Sink] = []
    probes = PipelineProbes()
    link = None
    if config.mqtt is not None:
        from edgedsm.publish.json_sink import MqttSink

        link = MqttSink(config.mqtt, config.device.state_dir, on_command).start()
        sinks.append(link)
    if config.sparkplug is not None and config.mqtt is not None:  # the config refuses one without the other
        from edgedsm.publish.sparkplug.node import SparkplugSink

        sinks.append(SparkplugSink(config.sparkplug, config.mqtt, config.device.state_dir,
                                   regions=[region.name for region in config.regions], maps=ESTIMATORS).start())
    if config.mqtt is not None and config.homeassistant is not None:
        from edgedsm.publish.homeassistant import HomeAssistantSink

        ha = config.homeassistant
        sinks.append(HomeAssistantSink(config.mqtt, ha.discovery_prefix, [r.name for r in config.regions],
                                       config.device.state_dir, colormap=ha.colormap if ha.color_maps else None
                                       ).start())
    if config.http is not None:
        from edgedsm.publish.prometheus import MetricsSink

        try:
            metrics = MetricsSink(config.http.stale_after_s, link=link).serve(config.http.address)
        except ConfigError:
            FanOut(sinks).close(1.0)  # the port is taken: release what was started
            raise
        sinks.append(metrics)
        probes = PipelineProbes(frame_taken=metrics.frame_taken, frame_pushed=metrics.frame_pushed)
    if link is None:
        sinks.insert(0, LogSink())
    return FanOut(sinks), probes


def couple_simulated_laser(camera: Camera, relay: LaserRelay | None) -> None:
    """A simulated camera sees speckle only while the simulated laser's contact is closed."""
    if isinstance(camera, SimulatedCamera) and isinstance(relay, SimulatedRelay):
        board = relay.board
        camera.illuminated = lambda: board.is_on


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
        self.laser_not_off: str | None = None  # why the laser could not be confirmed off at stop

    # -- signals ----------------------------------------------------------------------------
    def install_signal_handlers(self) -> None:
        signal.signal(signal.SIGTERM, self._on_stop_signal)
        signal.signal(signal.SIGINT, self._on_stop_signal)
        signal.signal(signal.SIGHUP, self._on_reload_signal)

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
        if self.config_path is None:
            log.warning("reload requested but the daemon was not started from a file")
            return False
        self.notifier.reloading()
        pipeline = self.pipeline
        try:
            new = check_reload(self.config_path, self.config, pipeline.frame_shape if pipeline else None)
        except ReloadRefused as exc:
            log.error("reload refused, keeping the running configuration: %s", exc)
            summary = str(exc).splitlines()[0].rstrip(":")
            if pipeline is not None:
                pipeline.evaluation.publish_alert(Alert(kind=AlertKind.WARNING, t=time.time(),
                                                        reason=f"reload refused, running configuration kept: {exc}"))
            self.notifier.ready(status=f"reload refused: {summary} (see the log)")
            return False
        log.warning("configuration reloaded from %s", self.config_path)
        self.config = new
        self._reloaded = True
        return True

    # -- running ----------------------------------------------------------------------------
    def run(self) -> int:
        """Measure until stopped; returns the process exit code."""
        while True:
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

    def _run_once(self) -> None:
        config = self.config
        camera = open_camera_for(config)  # touches no device until the pipeline opens it
        holder: dict[str, Pipeline] = {}

        def on_command(name: str, command: Command) -> dict[str, Any]:
            # called on the MQTT sink's command thread with a validated command
            pipeline = holder.get("pipeline")
            return pipeline.submit(name, command.model_dump()) if pipeline else {"ok": False, "error": "not running"}

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

        sink, probes = make_sink(config, on_command)
        try:
            # opened last and closed by LaserSafety (switched off) whatever happens after
            relay = open_relay(config.laser.spec) if config.laser is not None else None
            couple_simulated_laser(camera, relay)
            pipeline = Pipeline(config, camera, sink, relay=relay,
                                cadence=self.cadence or self._cadence(config), on_alive=alive,
                                probes=probes)
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
        finally:
            sink.close(1.0)  # 'offline' out within the 2 s a SIGTERM allows

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

    @staticmethod
    def _cadence(config: DaemonConfig) -> Cadence:
        if config.mqtt is None:
            return Cadence()
        return Cadence(stats_every_s=config.mqtt.stats_interval_s, maps_every_s=config.mqtt.maps_interval_s)
