"""The Home Assistant sink: MQTT discovery configs (``edgedsm.publish.ha_discovery``) and colour
maps for the image entities, on its own MQTT connection beside the JSON sink's.

- Configs are retained (QoS 1) and published again at every (re)connection and whenever Home
  Assistant announces itself (``<discovery_prefix>/status`` = ``online``).
- Entities that depend on data (one activity sensor per estimator the stats carry, one image
  per map) are announced when they first appear.
- The discovery topics published are remembered in ``<state_dir>/homeassistant-<device>.json``;
  at the next start an entity of a region no longer configured gets an empty retained config,
  which removes it from Home Assistant.
- Colour maps: the latest map per name waits for a worker thread that renders and publishes
  it (retained, QoS 0) on ``<base>/map/<name>/color``; ``publish_map`` never waits.
"""

from __future__ import annotations

import json
import logging
import os
import threading
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
import paho.mqtt.client as mqtt
from paho.mqtt.properties import Properties
from paho.mqtt.reasoncodes import ReasonCode

from edgedsm import _json
from edgedsm.errors import ConfigError
from edgedsm.messages import Alert, MapFrame, StateReport, Stats
from edgedsm.publish.colormap import encode_colour_png
from edgedsm.publish.connection import build_ssl_context, connect_in_background, make_client
from edgedsm.publish.ha_discovery import Discovery, Entity, colour_map_topic
from edgedsm.publish.latest_worker import LatestWorker
from edgedsm.publish.settings import MqttSettings, resolve_password
from edgedsm.publish.topics import Topics

log = logging.getLogger(__name__)


class HomeAssistantSink:
    """Implements :class:`edgedsm.publish.sink.Sink` for Home Assistant (see the module docstring).

    ``regions``: the configured region names; ``colormap``: an OpenCV colour map name, or None
    for no colour maps (and no image entities).
    """

    def __init__(self, settings: MqttSettings, discovery_prefix: str, regions: Iterable[str], state_dir: str | Path,
                 *, colormap: str | None = "turbo", password: str | None = None) -> None:
        self.settings = settings
        self.topics = Topics.from_settings(settings)
        self.discovery = Discovery(discovery_prefix, self.topics, settings.device)
        self.regions = list(regions)
        self.colormap = colormap
        self.status_topic = f"{self.discovery.prefix}/status"
        self.memory = Path(state_dir) / f"homeassistant-{settings.device}.json"
        self._lock = threading.Lock()
        self._entities: dict[str, Entity] = {}
        for entity in self.discovery.device_entities():
            self._entities[entity.topic] = entity
        for region in self.regions:
            for entity in self.discovery.region_entities(region):
                self._entities[entity.topic] = entity
        self._stale = self._forgotten_topics()
        self._connected = threading.Event()
        self._maps: LatestWorker[np.ndarray] = LatestWorker("edgedsm-ha-maps", "Home Assistant colour map",
                                                            self._render)
        self.maps_sent = 0
        password = password if password is not None else resolve_password()
        ssl_context = build_ssl_context(settings.tls) if settings.tls is not None else None
        self._client = make_client(settings, client_id=f"{settings.effective_client_id}-ha"[:128], password=password,
                                   ssl_context=ssl_context)
        self._client.on_connect = self._on_connect
        self._client.on_disconnect = self._on_disconnect
        self._client.message_callback_add(self.status_topic, self._on_status)

    def start(self) -> HomeAssistantSink:
        """Connect in the background (returns at once)."""
        connect_in_background(self._client, self.settings)
        if self.colormap is not None:
            self._maps.start()
        return self

    @property
    def connected(self) -> bool:
        return self._connected.is_set()

    def entities(self) -> list[Entity]:
        with self._lock:
            return list(self._entities.values())

    # -- remembering what was announced ------------------------------------------------------------
    def _forgotten_topics(self) -> list[str]:
        """Topics announced by an earlier run for regions no longer configured."""
        try:
            remembered = json.loads(self.memory.read_text(encoding="utf-8"))
        except FileNotFoundError:
            return []
        except (OSError, ValueError) as exc:
            log.warning("Home Assistant: %s unreadable (%s); no entity will be removed", self.memory, exc)
            return []
        if not isinstance(remembered, dict):
            return []
        return sorted(topic for topic, region in remembered.items()
                      if isinstance(topic, str) and region is not None and region not in self.regions
                      and topic not in self._entities)

    def _remember(self) -> None:
        with self._lock:
            known = {topic: entity.region for topic, entity in self._entities.items()}
        try:
            self.memory.parent.mkdir(parents=True, exist_ok=True)
            temporary = self.memory.with_suffix(".tmp")
            temporary.write_text(json.dumps(known, indent=1, sort_keys=True), encoding="utf-8")
            os.replace(temporary, self.memory)
        except OSError as exc:
            raise ConfigError(f"device.state_dir: cannot write {self.memory}: {exc.strerror or exc}") from None

    # -- MQTT (paho's thread) -------------------------------------------------------------------------
    def _on_connect(self, client: mqtt.Client, userdata: Any, flags: Any, reason: ReasonCode,
                    properties: Properties | None) -> None:
        if reason.is_failure:
            log.error("Home Assistant: broker refused the connection: %s", reason)
            return
        client.subscribe(self.status_topic, qos=1)
        for topic in self._stale:
            client.publish(topic, b"", qos=1, retain=True)
            log.info("Home Assistant: removed %s (its region is no longer configured)", topic)
        self._stale = []
        self._announce(self.entities())
        self._connected.set()
        try:
            self._remember()
        except ConfigError as exc:
            log.error("Home Assistant: %s", exc)

    def _on_disconnect(self, client: mqtt.Client, userdata: Any, flags: Any, reason: ReasonCode,
                       properties: Properties | None) -> None:
        self._connected.clear()

    def _on_status(self, client: mqtt.Client, userdata: Any, message: mqtt.MQTTMessage) -> None:
        if message.payload == b"online":  # Home Assistant (re)started: announce again
            self._announce(self.entities())

    def _announce(self, entities: Iterable[Entity]) -> None:
        for entity in entities:
            self._client.publish(entity.topic, _json.dumps(entity.config), qos=1, retain=True)

    def _add(self, entities: Iterable[Entity]) -> None:
        """Announce entities not announced yet."""
        with self._lock:
            new = [entity for entity in entities if entity.topic not in self._entities]
            for entity in new:
                self._entities[entity.topic] = entity
        if new and self.connected:
            self._announce(new)
            try:
                self._remember()
            except ConfigError as exc:
                log.error("Home Assistant: %s", exc)

    # -- the Sink protocol ----------------------------------------------------------------------------
    def publish_state(self, report: StateReport) -> None:
        return None  # Home Assistant reads <base>/state itself

    def publish_alert(self, alert: Alert) -> None:
        return None

    def publish_stats(self, stats: Stats) -> None:
        self._add(self.discovery.activity_entity(region, estimator)
                  for region, maps in stats.regions.items() if region in self.regions for estimator in maps)
        self._add(self.discovery.tau_entity(region) for region in stats.tau_c if region in self.regions)

    def publish_map(self, frame: MapFrame) -> None:
        if self.colormap is None:
            return
        self._add([self.discovery.image_entity(frame.name)])
        self._maps.submit(frame.name, frame.values)  # the latest replaces one not yet rendered

    def flush(self, timeout_s: float) -> bool:
        return True

    def close(self, timeout_s: float) -> None:
        self._maps.stop(timeout_s=max(0.0, timeout_s / 2))
        self._client.disconnect()
        stopper = threading.Thread(target=self._client.loop_stop, daemon=True)
        stopper.start()
        stopper.join(timeout=max(0.0, timeout_s / 2))

    # -- colour maps (worker thread) -----------------------------------------------------------------
    def _render(self, name: str, values: np.ndarray) -> None:
        if not self.connected:
            return
        png = encode_colour_png(values, colormap=self.colormap or "turbo", max_size=self.settings.map_max_size,
                                title=name.upper(), compression=self.settings.map_png_compression)
        self._client.publish(colour_map_topic(self.topics, name), png, qos=0, retain=True)
        self.maps_sent += 1
