"""The daemon's sinks, kept across reloads: a sink whose settings did not change keeps its
session (no ``offline``/``online``, no new Sparkplug ``bdSeq``); one whose settings changed is
closed and built again, and so is every sink built on it (Home Assistant publishes through the
JSON link's session). The one place sinks are registered (``docs/architecture.md``).
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from edgedsm.config import DaemonConfig
from edgedsm.daemon.probes import PipelineProbes
from edgedsm.daemon.recording import Recorder
from edgedsm.daemon.tau import engine_estimators
from edgedsm.errors import ConfigError
from edgedsm.publish.command_channel import CommandHandler
from edgedsm.publish.sink import FanOut, LogSink, Sink

log = logging.getLogger(__name__)


def _fingerprint(*parts: Any) -> str:
    """What a sink is built from, comparable across configs."""
    return json.dumps([part.model_dump(mode="json") if hasattr(part, "model_dump") else part for part in parts],
                      sort_keys=True, default=str)


def _broker(config: DaemonConfig) -> dict[str, Any]:
    assert config.mqtt is not None
    return config.mqtt.model_dump(mode="json")


def _regions(config: DaemonConfig) -> list[str]:
    return [region.name for region in config.regions]


def _build_mqtt(config: DaemonConfig, on_command: CommandHandler, needed: Sink | None) -> Sink:
    from edgedsm.publish.json_sink import MqttSink

    assert config.mqtt is not None
    return MqttSink(config.mqtt, config.device.state_dir, on_command).start()


def _build_sparkplug(config: DaemonConfig, on_command: CommandHandler, needed: Sink | None) -> Sink:
    from edgedsm.publish.sparkplug.node import SparkplugSink

    assert config.mqtt is not None and config.sparkplug is not None
    return SparkplugSink(config.sparkplug, config.mqtt, config.device.state_dir, regions=_regions(config),
                         maps=engine_estimators(config), signal=config.estimator.noise_floor,
                         judged={region.name: "tau_c" if region.on_tau else config.estimator.activity
                                 for region in config.regions}).start()


def _build_homeassistant(config: DaemonConfig, on_command: CommandHandler, needed: Sink | None) -> Sink:
    from edgedsm.publish.homeassistant import HomeAssistantSink
    from edgedsm.publish.json_sink import MqttSink

    ha = config.homeassistant
    assert isinstance(needed, MqttSink) and ha is not None  # SINKS: homeassistant needs mqtt
    return HomeAssistantSink(needed.session, ha.discovery_prefix, _regions(config), config.device.state_dir,
                             colormap=ha.colormap if ha.color_maps else None).start()


def _build_http(config: DaemonConfig, on_command: CommandHandler, needed: Sink | None) -> Sink:
    from edgedsm.publish.prometheus import MetricsSink

    assert config.http is not None
    return MetricsSink(config.http.stale_after_s).serve(config.http.address)


def _build_recording(config: DaemonConfig, on_command: CommandHandler, needed: Sink | None) -> Sink:
    from edgedsm.daemon.recording import make_recorder

    assert config.recording is not None and config.recording_dir is not None
    return make_recorder(config.recording, config.recording_dir, config.device.name, config.camera.uri,
                         config.source)


def _http_moves(new: DaemonConfig, running: DaemonConfig | None) -> bool:
    return running is not None and running.http is not None and new.http is not None \
        and running.http.address != new.http.address


@dataclass(frozen=True)
class SinkSpec:
    """One kind of sink: whether a config asks for it, what it is built from (a fingerprint:
    the sink is rebuilt when it changes), how to build it, and whether a new one can start while
    the running one still runs (a metrics server moving to another address can; an MQTT client
    cannot, the broker throws off the older of two clients with one id, nor a server on the same
    address). ``needs``: the sink this one is built on (listed before it, wanted whenever it is);
    ``build`` is handed it, and it being rebuilt rebuilds this one."""

    name: str
    wanted: Callable[[DaemonConfig], bool]
    fingerprint: Callable[[DaemonConfig], str]
    build: Callable[[DaemonConfig, CommandHandler, Sink | None], Sink]
    beside: Callable[[DaemonConfig, DaemonConfig | None], bool] = lambda new, running: False
    needs: str | None = None


#: Every sink the daemon can run, in fan-out order: the one table of sinks.
SINKS: tuple[SinkSpec, ...] = (
    SinkSpec("log", lambda c: c.mqtt is None, lambda c: "", lambda c, on_command, needed: LogSink()),
    SinkSpec("mqtt", lambda c: c.mqtt is not None,
             lambda c: _fingerprint(_broker(c), str(c.device.state_dir)), _build_mqtt),
    SinkSpec("sparkplug", lambda c: c.mqtt is not None and c.sparkplug is not None,
             lambda c: _fingerprint(c.sparkplug, _broker(c), str(c.device.state_dir), _regions(c),
                                    c.estimator.noise_floor), _build_sparkplug),
    SinkSpec("homeassistant", lambda c: c.mqtt is not None and c.homeassistant is not None,
             lambda c: _fingerprint(c.homeassistant, str(c.device.state_dir), _regions(c)), _build_homeassistant,
             needs="mqtt"),
    SinkSpec("http", lambda c: c.http is not None, lambda c: _fingerprint(c.http), _build_http, _http_moves),
    # [recording]: a sink for the alerts that start clips, and the pipeline's frame consumer
    SinkSpec("recording", lambda c: c.recording is not None,
             lambda c: _fingerprint(c.recording, str(c.recording_dir), c.device.name, c.camera.uri), _build_recording),
)
_SPECS = {spec.name: spec for spec in SINKS}


def wanted_sinks(config: DaemonConfig) -> dict[str, str]:
    """Each sink the config asks for, in fan-out order, with the fingerprint of its settings; a
    sink built on another one (``needs``) has that one's fingerprint in its own, so it is
    rebuilt with it."""
    wanted: dict[str, str] = {}
    for spec in SINKS:
        if spec.wanted(config):
            own = spec.fingerprint(config)
            wanted[spec.name] = own if spec.needs is None else _fingerprint(own, wanted[spec.needs])
    return wanted


class SinkSet:
    """Every configured sink behind one :class:`FanOut` and one :class:`PipelineProbes`, both
    kept for the daemon's life (a restarted pipeline is handed the same ones)."""

    def __init__(self, on_command: CommandHandler) -> None:
        self.on_command = on_command
        self.fanout = FanOut([])
        self.probes = PipelineProbes()
        self._built: dict[str, tuple[str, Sink]] = {}
        self._config: DaemonConfig | None = None  # the config the sinks were last built for

    def apply(self, config: DaemonConfig) -> list[str]:
        """Build, keep or rebuild each sink for ``config``; returns the names (re)built or closed.
        A sink that cannot start (a taken port) is a ConfigError. Sinks that can start beside the
        running ones (one new to this config, a metrics server moving to another address) start
        first: when one of them cannot, nothing running was touched."""
        wanted = wanted_sinks(config)
        changed = [name for name in _SPECS if name in self._built and self._built[name][0] != wanted.get(name)]
        early: dict[str, Sink] = {}
        try:
            for name in wanted:  # in SINKS order: a needed sink before the sinks built on it
                need = _SPECS[name].needs
                waits = need is not None and need in changed and need not in early  # built again later
                if not waits and (name not in self._built or (name in changed and self._beside(name, config))):
                    early[name] = self._build(name, config, early)
        except ConfigError:
            for name, sink in reversed(early.items()):
                _close(name, sink)
            raise
        # closed first (a new client with the same id would be thrown off), a sink built on
        # another before that one
        for name in reversed(changed):
            _, sink = self._built.pop(name)
            self.fanout.sinks = [s for s in self.fanout.sinks if s is not sink]
            _close(name, sink)
        built = [name for name in wanted if name not in self._built]
        self._built.update({name: (wanted[name], sink) for name, sink in early.items()})
        self._config = config
        for name in built:
            if name not in early:
                self._built[name] = (wanted[name], self._build(name, config, early))
        self.fanout.sinks = [self._built[name][1] for name in wanted]
        self._wire(config)
        if changed or built:
            log.info("sinks built: %s; closed: %s", ", ".join(built) or "none", ", ".join(changed) or "none")
        return sorted(set(changed) | set(built))

    def _beside(self, name: str, config: DaemonConfig) -> bool:
        """Whether the sink ``name`` for ``config`` can start while the running one still runs."""
        return _SPECS[name].beside(config, self._config)

    def _build(self, name: str, config: DaemonConfig, early: Mapping[str, Sink]) -> Sink:
        """Build ``name``, handing it the sink it needs: one just built (``early``) or the running one."""
        need = _SPECS[name].needs
        needed = None if need is None else early[need] if need in early else self._built[need][1]
        return _SPECS[name].build(config, self.on_command, needed)

    def _wire(self, config: DaemonConfig) -> None:
        """The metrics sink reads the MQTT link's health and is the pipeline's frame probes."""
        metrics = self.get("http")
        self.probes.frame_taken = self.probes.frame_pushed = None
        if metrics is None:
            return
        from edgedsm.publish.json_sink import MqttSink
        from edgedsm.publish.prometheus import MetricsSink

        assert isinstance(metrics, MetricsSink)  # _build makes "http" a MetricsSink
        link = self.get("mqtt")
        metrics.link = link if isinstance(link, MqttSink) else None
        self.probes.frame_taken = metrics.frame_taken
        self.probes.frame_pushed = metrics.frame_pushed

    @property
    def recorder(self) -> Recorder | None:
        """The ``[recording]`` recorder, to hand the pipeline (None without one)."""
        recorder = self.get("recording")
        assert recorder is None or isinstance(recorder, Recorder)
        return recorder

    def get(self, name: str) -> Sink | None:
        built = self._built.get(name)
        return built[1] if built else None

    def close(self, timeout_s: float) -> None:
        self._built.clear()
        self._config = None
        self.fanout.close(timeout_s)
        self.fanout.sinks = []


def _close(name: str, sink: Sink) -> None:
    try:
        sink.close(1.0)
    except Exception as exc:  # a sink that fails to close must not keep the others from their turn
        log.error("%s: close failed: %s", name, exc)


def make_sink(config: DaemonConfig, on_command: CommandHandler) -> tuple[Sink, PipelineProbes]:
    """Every configured sink for ``config`` behind one FanOut, and the probes they measure the
    pipeline with (see :class:`SinkSet`); a sink that cannot start closes those started."""
    sinks = SinkSet(on_command)
    try:
        sinks.apply(config)
    except ConfigError:
        sinks.close(1.0)  # the port is taken: release what was started
        raise
    return sinks.fanout, sinks.probes

