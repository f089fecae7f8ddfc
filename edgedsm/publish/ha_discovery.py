"""Home Assistant MQTT discovery payloads for one edgedsm device (pure: topics and JSON only).

Every entity belongs to ONE device (``device`` block: identifiers, name, model, sw_version) and
is available while ``<base>/availability`` says ``online``. State topics are the daemon's own
(``docs/mqtt.md``) read with ``value_template``s; nothing is published twice:

- per region: ``<region> state`` (enum sensor, the five states) and ``<region> time to dry``
  (duration, s) from the retained ``<base>/state``; ``<region> activity``, the value the
  thresholds judge (the stats' ``activity``, the state report's number), in its estimator's unit;
  ``<region> <label> mean``, the plain region mean of each map the stats carry (new maps appear
  by themselves), in the map's unit (labels and units: ``edgedsm.publish.units``, the registry's);
- per region, once the stats carry its signal (``estimator.noise_floor``): ``<region> signal``
  (enum sensor, the five verdicts, with the whole signal as attributes: reason, fractions,
  floor ...) and ``<region> above noise`` (the activity above the camera's noise floor);
- the laser (read-only binary sensor) from ``<base>/stats``; the link (connectivity binary sensor)
  from ``<base>/availability``;
- per map: an ``image`` entity on ``<base>/map/<name>/color`` (8-bit colour PNG with colour bar).

Templates render ``None`` for a missing value, which Home Assistant shows as unknown.
Discovery topics are ``<discovery_prefix>/<component>/<node_id>/<object_id>/config``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any, get_args

from edgedsm import __version__
from edgedsm.messages import SignalName
from edgedsm.publish.topics import Topics
from edgedsm.publish.units import display_unit, label_of, unit_of

STATES = ["warming_up", "wet", "drying", "dry", "fault"]
#: The five signal verdicts (docs/noise.md).
SIGNALS = list(get_args(SignalName))


def slug(text: str) -> str:
    """``text`` with every character Home Assistant refuses in ids replaced by ``_``."""
    return re.sub(r"[^A-Za-z0-9_-]", "_", text)


def _unit(unit: str) -> dict[str, str]:
    """``unit_of_measurement`` for a unit; none for a dimensionless value (Home Assistant shows
    the bare number)."""
    shown = display_unit(unit)
    return {} if shown is None else {"unit_of_measurement": shown}


def colour_map_topic(topics: Topics, name: str) -> str:
    """Where the colour picture of map ``name`` goes, beside the exact 16-bit one."""
    return f"{topics.map(name)}/color"


@dataclass(frozen=True)
class Entity:
    """One discovery config: where it goes, what it says, and the region it belongs to (if any)."""

    topic: str
    config: dict[str, Any]
    region: str | None = None


class Discovery:
    """Builds the discovery configs of one device (``topics``) under ``prefix``."""

    def __init__(self, prefix: str, topics: Topics, device: str) -> None:
        self.prefix = prefix.strip("/")
        self.topics = topics
        self.node = slug(f"edgedsm_{device}")
        self.identifier = slug(f"edgedsm_{topics.base}")
        self.device_block = {"identifiers": [self.identifier], "name": f"edgedsm {device}",
                             "manufacturer": "edgedsm", "model": "dynamic speckle activity monitor",
                             "sw_version": __version__}

    def _entity(self, component: str, key: str, config: dict[str, Any], region: str | None = None,
                available: bool = True) -> Entity:
        object_id = slug(key)
        payload: dict[str, Any] = {"unique_id": f"{self.identifier}_{object_id}", **config,
                                   "device": self.device_block,
                                   "origin": {"name": "edgedsm", "sw_version": __version__}}
        if available:
            payload.update(availability_topic=self.topics.availability, payload_available="online",
                           payload_not_available="offline")
        return Entity(f"{self.prefix}/{component}/{self.node}/{object_id}/config", payload, region)

    @staticmethod
    def _region_value(region: str, key: str) -> str:
        return f"{{{{ value_json.get('regions', {{}}).get('{region}', {{}}).get('{key}') }}}}"

    def region_entities(self, region: str) -> list[Entity]:
        """A region's drying state and time to dry."""
        return [
            self._entity("sensor", f"{region}_state", {
                "name": f"{region} state", "state_topic": self.topics.state, "device_class": "enum",
                "options": STATES, "value_template": self._region_value(region, "state"),
                "icon": "mdi:water-percent"}, region),
            self._entity("sensor", f"{region}_time_to_dry", {
                "name": f"{region} time to dry", "state_topic": self.topics.state, "device_class": "duration",
                "unit_of_measurement": "s", "value_template": self._region_value(region, "time_to_dry_s")},
                region),
        ]

    def activity_entity(self, region: str, unit: str) -> Entity:
        """The value the region's thresholds judge (the stats' ``activity``), in ``unit``; None
        (unknown) while it is held."""
        template = f"{{{{ value_json.get('activity', {{}}).get('{region}', {{}}).get('value') }}}}"
        return self._entity("sensor", f"{region}_activity", {
            "name": f"{region} activity", "state_topic": self.topics.stats, "state_class": "measurement",
            "value_template": template, "icon": "mdi:chart-bell-curve", **_unit(unit)}, region)

    def map_mean_entity(self, region: str, name: str) -> Entity:
        """The plain region mean of map ``name`` (no noise floor removed), from the stats."""
        template = (f"{{{{ value_json.get('regions', {{}}).get('{region}', {{}}).get('{name}', {{}})"
                    f".get('mean') }}}}")
        return self._entity("sensor", f"{region}_{name}", {
            "name": f"{region} {label_of(name)} mean", "state_topic": self.topics.stats,
            "state_class": "measurement", "value_template": template, "icon": "mdi:chart-bell-curve",
            **_unit(unit_of(name))}, region)

    def tau_entity(self, region: str) -> Entity:
        """The region's correlation time τc in seconds (its pooled fit), from the stats."""
        template = (f"{{{{ value_json.get('tau_c', {{}}).get('{region}', {{}})"
                    f".get('tau_c_s') }}}}")
        return self._entity("sensor", f"{region}_tau_c", {
            "name": f"{region} {label_of('tau_c')}", "state_topic": self.topics.stats, "state_class": "measurement",
            "device_class": "duration", **_unit(unit_of("tau_c")), "value_template": template,
            "icon": "mdi:timer-sand"}, region)

    def kinetics_entity(self, region: str) -> Entity:
        """The region's decorrelation time over decades (``[kinetics]``) in the registry's unit,
        from the stats; unknown where there is no number (its status says why)."""
        template = f"{{{{ value_json.get('kinetics', {{}}).get('{region}', {{}}).get('tau_s') }}}}"
        return self._entity("sensor", f"{region}_kinetics", {
            "name": f"{region} {label_of('kinetics')}", "state_topic": self.topics.stats,
            "state_class": "measurement", "device_class": "duration", **_unit(unit_of("kinetics")),
            "value_template": template, "icon": "mdi:timer-sand"}, region)

    def signal_entities(self, region: str) -> list[Entity]:
        """The region's signal quality (with every number of its signal as attributes) and its
        activity above the camera's noise floor, from the stats (docs/noise.md)."""
        signal = f"value_json.get('signal', {{}}).get('{region}', {{}})"
        return [
            self._entity("sensor", f"{region}_signal", {
                "name": f"{region} signal", "state_topic": self.topics.stats, "device_class": "enum",
                "options": SIGNALS, "value_template": f"{{{{ {signal}.get('signal') }}}}",
                "json_attributes_topic": self.topics.stats, "json_attributes_template": f"{{{{ {signal} | tojson }}}}",
                "icon": "mdi:signal-variant"}, region),
            self._entity("sensor", f"{region}_above_noise", {
                "name": f"{region} above noise", "state_topic": self.topics.stats, "state_class": "measurement",
                "value_template": f"{{{{ {signal}.get('above_noise') }}}}", "icon": "mdi:chart-bell-curve"}, region),
        ]

    def device_entities(self) -> list[Entity]:
        """The laser (read-only) and the device's link to the broker."""
        return [
            self._entity("binary_sensor", "laser", {
                "name": "laser", "state_topic": self.topics.stats, "device_class": "light",
                "value_template": "{{ {'on': 'ON', 'off': 'OFF'}.get(value_json.get('laser'), 'None') }}",
                "payload_on": "ON", "payload_off": "OFF", "entity_category": "diagnostic"}),
            self._entity("binary_sensor", "online", {
                "name": "online", "state_topic": self.topics.availability, "device_class": "connectivity",
                "payload_on": "online", "payload_off": "offline", "entity_category": "diagnostic"},
                available=False),
        ]

    def image_entity(self, name: str) -> Entity:
        """The colour picture of map ``name``."""
        return self._entity("image", f"map_{name}", {
            "name": f"{label_of(name)} map", "image_topic": colour_map_topic(self.topics, name),
            "content_type": "image/png"})
