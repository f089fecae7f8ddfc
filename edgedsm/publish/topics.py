"""Every MQTT topic of one device, ``<topic_prefix>/<device>/...`` (documented in ``docs/mqtt.md``)."""

from __future__ import annotations

from dataclasses import dataclass

from edgedsm.publish.settings import MqttSettings


@dataclass(frozen=True)
class Topics:
    """Every topic of one device, from ``<prefix>/<device>``."""

    base: str

    @classmethod
    def of(cls, prefix: str, device: str) -> Topics:
        return cls(f"{prefix.strip('/')}/{device}")

    @classmethod
    def from_settings(cls, settings: MqttSettings) -> Topics:
        return cls.of(settings.topic_prefix, settings.device)

    @property
    def prefix(self) -> str:
        """``<topic_prefix>``: every edgedsm device publishes under it."""
        return self.base.rpartition("/")[0]

    @property
    def availability(self) -> str:
        return f"{self.base}/availability"

    @property
    def state(self) -> str:
        return f"{self.base}/state"

    def region_state(self, region: str) -> str:
        """One region's retained ``RegionState``, beside the combined ``state``."""
        return f"{self.base}/state/{region}"

    @property
    def region_states_filter(self) -> str:
        """Subscription for every region's state."""
        return f"{self.base}/state/+"

    @property
    def alerts(self) -> str:
        return f"{self.base}/alerts"

    @property
    def stats(self) -> str:
        return f"{self.base}/stats"

    def map(self, name: str) -> str:
        return f"{self.base}/map/{name}"

    def map_meta(self, name: str) -> str:
        return f"{self.base}/map/{name}/meta"

    @property
    def maps_filter(self) -> str:
        """Subscription for every map PNG; metas are ``map/+/meta``."""
        return f"{self.base}/map/+"

    def command(self, name: str) -> str:
        return f"{self.base}/cmd/{name}"

    @property
    def command_filter(self) -> str:
        """What the publisher subscribes to (one level, so replies are not matched)."""
        return f"{self.base}/cmd/+"

    def reply(self, name: str) -> str:
        return f"{self.base}/cmd/{name}/reply"

    @property
    def replies_filter(self) -> str:
        """Subscription for every command reply."""
        return f"{self.base}/cmd/+/reply"
