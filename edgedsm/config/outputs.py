"""The tables of what a daemon config publishes and logs, beside ``[mqtt]`` and ``[sparkplug]``
(their models live with their sinks): ``[cadence]``, ``[logging]``, ``[homeassistant]``, ``[http]``."""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator

from edgedsm.publish.settings import TopicPrefix
from edgedsm.validation import StrictModel


class LoggingSection(StrictModel):
    level: Literal["debug", "info", "warning", "error"] = Field("info", description="log level")
    json_lines: bool = Field(False, description="one JSON object per log line (for log shippers)")


class CadenceSection(StrictModel):
    """``[cadence]``: how often the pipeline evaluates and publishes statistics and maps, for
    every sink (the drying states are judged twice a second whatever these say)."""

    stats_interval_s: float = Field(5.0, ge=0.1, le=3600.0,
                                    description="seconds between statistics messages")
    maps_interval_s: float = Field(60.0, ge=0.1, le=86_400.0,
                                   description="seconds between map messages (cmd/publish_maps asks for one at once)")


class HomeAssistantSection(StrictModel):
    """``[homeassistant]``: MQTT discovery of this device's entities (needs ``[mqtt]``)."""

    discovery_prefix: TopicPrefix = Field(
        "homeassistant", description="Home Assistant's discovery prefix (its MQTT integration setting)")
    color_maps: bool = Field(True, description="publish colour-mapped 8-bit PNG maps on <base>/map/<name>/color "
                                               "(with a colour bar) and announce them as image entities")
    colormap: Literal["turbo", "viridis", "inferno", "jet"] = Field("turbo", description="OpenCV colour map")


class HttpSection(StrictModel):
    """``[http]``: Prometheus ``/metrics`` and ``/healthz`` on a small HTTP server."""

    listen: str = Field("127.0.0.1:9108", min_length=3, max_length=64, pattern=r"^[^\s:]+:\d{1,5}$",
                        description="HOST:PORT to listen on (127.0.0.1 keeps it on this machine)")
    stale_after_s: float = Field(10.0, gt=0, le=3600,
                                 description="/healthz says 503 when no frame arrived for this long")

    @field_validator("listen")
    @classmethod
    def _port_in_range(cls, value: str) -> str:
        if not 1 <= int(value.rpartition(":")[2]) <= 65535:
            raise ValueError("the port must be 1..65535")
        return value

    @property
    def address(self) -> tuple[str, int]:
        host, _, port = self.listen.rpartition(":")
        return host, int(port)
