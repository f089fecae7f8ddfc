"""The Home Assistant sink: MQTT discovery configs (``edgedsm.publish.ha_discovery``) and colour
maps for the image entities, published through the JSON link's MQTT session (no connection of
its own: the broker sees one client for the JSON topics and Home Assistant).

- Configs are retained (QoS 1) and published again at every (re)connection of that session and
  whenever Home Assistant announces itself (``<discovery_prefix>/status`` = ``online``, a
  subscription on the shared session).
- Entities that depend on data (one activity sensor per estimator the stats carry, a region's τc
  and signal sensors, one image per map) are announced when they first appear.
- The discovery topics published are remembered in ``<state_dir>/homeassistant-<device>.json``;
  at the next start an entity of a region no longer configured gets an empty retained config,
  which removes it from Home Assistant.
- Colour maps: the latest map per name waits for a worker thread that renders and publishes
  it (retained, QoS 0) on ``<base>/map/<name>/color``; ``publish_map`` never waits.

The session belongs to the JSON link: closing this sink leaves it (and ``online``) alone.
"""

from __future__ import annotations

import json
import logging
import os
import threading
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import paho.mqtt.client as mqtt

from edgedsm import _json
from edgedsm.errors import ConfigError
from edgedsm.messages import Alert, MapFrame, StateReport, Stats
from edgedsm.publish.colormap import encode_colour_png
from edgedsm.publish.ha_discovery import Discovery, Entity, colour_map_topic
from edgedsm.publish.latest_worker import LatestWorker
from edgedsm.publish.session import MqttSession
from edgedsm.publish.topics import Topics

log = logging.getLogger(__name__)


class HomeAssistantSink:
    """Implements :class:`edgedsm.publish.sink.Sink` for Home Assistant (see the module docstring).

    ``session``: the JSON link's (:attr:`edgedsm.publish.json_sink.MqttSink.session`), started by
    its owner; ``regions``: the configured region names; ``colormap``: an OpenCV colour map
    name, or None for no colour maps (and no image entities).
    """

    def __init__(self, session: MqttSession, discovery_prefix: str, regions: Iterable[str], state_dir: str | Path,
                 *, colormap: str | None = "turbo") -> None:
        self.session = session
        self.settings = settings = session.settings
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
        self._maps: LatestWorker[np.ndarray] = LatestWorker("edgedsm-ha-maps", "Home Assistant colour map",
                                                            self._render)
        self._attached = False
        self.maps_sent = 0

    def start(self) -> HomeAssistantSink:
        """Attach to the session: announce now if it is connected, and at every connection to
        come (returns at once)."""
        if not self._attached:
            self._attached = True
            self.session.subscribe(self.status_topic, 1, self._on_status, what="Home Assistant's restarts")
            self.session.on_connected(self._on_connected)
        if self.colormap is not None:
            self._maps.start()
        return self

    @property
    def connected(self) -> bool:
        """Whether the shared session is connected."""
        return self.session.connected.is_set()

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

    # -- MQTT (paho's network thread, or the caller's when attached to a connected session) ----------
    def _on_connected(self) -> None:
        with self._lock:  # cleared once, by the first connection that runs this
            stale, self._stale = self._stale, []
        for topic in stale:
            self.session.client.publish(topic, b"", qos=1, retain=True)
            log.info("Home Assistant: removed %s (its region is no longer configured)", topic)
        self._announce(self.entities())
        try:
            self._remember()
        except ConfigError as exc:
            log.error("Home Assistant: %s", exc)

    def _on_status(self, message: mqtt.MQTTMessage) -> None:
        if message.payload == b"online":  # Home Assistant (re)started: announce again
            self._announce(self.entities())

    def _announce(self, entities: Iterable[Entity]) -> None:
        for entity in entities:
            self.session.client.publish(entity.topic, _json.dumps(entity.config), qos=1, retain=True)

    def _add(self, entities: Iterable[Entity]) -> None:
        """Announce entities not announced yet, or announced with another config (a unit that
        changed with the estimator on reload)."""
        with self._lock:
            new = [entity for entity in entities
                   if entity.topic not in self._entities or self._entities[entity.topic].config != entity.config]
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
        self._add(self.discovery.activity_entity(region, judged.unit)
                  for region, judged in stats.activity.items() if region in self.regions)
        # a τc map's region mean would take the object id of the pooled τc's own sensor (tau_entity)
        self._add(self.discovery.map_mean_entity(region, name)
                  for region, maps in stats.regions.items() if region in self.regions for name in maps
                  if name != "tau_c")
        self._add(self.discovery.tau_entity(region) for region in stats.tau_c if region in self.regions)
        self._add(self.discovery.kinetics_entity(region) for region in stats.kinetics if region in self.regions)
        self._add(entity for region in stats.signal if region in self.regions
                  for entity in self.discovery.signal_entities(region))

    def publish_map(self, frame: MapFrame) -> None:
        if self.colormap is None:
            return
        self._add([self.discovery.image_entity(frame.name)])
        self._maps.submit(frame.name, frame.values)  # the latest replaces one not yet rendered

    def flush(self, timeout_s: float) -> bool:
        return True

    def close(self, timeout_s: float) -> None:
        """Stop the colour maps and leave the session (which stays connected for its owner)."""
        if self._attached:
            self._attached = False
            self.session.remove_hooks(self._on_connected)
            self.session.unsubscribe(self.status_topic, self._on_status)
        self._maps.stop(timeout_s=max(0.0, timeout_s))

    # -- colour maps (worker thread) -----------------------------------------------------------------
    def _render(self, name: str, values: np.ndarray) -> None:
        if not self.connected:
            return
        png = encode_colour_png(values, colormap=self.colormap or "turbo", max_size=self.settings.map_max_size,
                                title=name.upper(), compression=self.settings.map_png_compression)
        self.session.client.publish(colour_map_topic(self.topics, name), png, qos=0, retain=True)
        self.maps_sent += 1
