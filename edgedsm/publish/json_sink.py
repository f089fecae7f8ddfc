"""The MQTT JSON sink: the daemon's typed messages as JSON on ``<prefix>/<device>/...``.

A thin layer over :class:`edgedsm.publish.mqtt.MqttPublisher` (connection, durable alerts, map
encoding, commands); topics and payloads are documented in ``docs/mqtt.md``.
"""

from __future__ import annotations

from pathlib import Path

from edgedsm.messages import Alert, MapFrame, StateReport, Stats
from edgedsm.publish.mqtt import CommandHandler, MqttPublisher
from edgedsm.publish.settings import MqttSettings


class MqttSink:
    """Implements :class:`edgedsm.publish.sink.Sink` over MQTT (JSON payloads, PNG maps)."""

    def __init__(self, settings: MqttSettings, state_dir: str | Path, on_command: CommandHandler | None = None,
                 *, password: str | None = None) -> None:
        self.publisher = MqttPublisher(settings, state_dir, on_command, password=password)

    def start(self) -> MqttSink:
        """Start connecting in the background (returns at once)."""
        self.publisher.start()
        return self

    def publish_state(self, report: StateReport) -> None:
        self.publisher.publish_state(report.to_json())

    def publish_alert(self, alert: Alert) -> None:
        # seq and stream are given by the durable queue
        self.publisher.publish_alert(alert.model_copy(update={"seq": None, "stream": None}).to_json())

    def publish_stats(self, stats: Stats) -> None:
        self.publisher.publish_stats(stats.to_json())

    def publish_map(self, frame: MapFrame) -> None:
        self.publisher.publish_map(frame.name, frame.values, frame.meta())

    def flush(self, timeout_s: float) -> bool:
        return self.publisher.flush_maps(timeout_s)

    def close(self, timeout_s: float) -> None:
        self.publisher.close(timeout=timeout_s)
