"""Wires the dashboard: history database, plant view, event hub, MQTT subscriber, HTTP server."""

from __future__ import annotations

import ipaddress
import logging
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from edgedsm.dashboard.access import AccessSettings, ViewerLogin, tls_context
from edgedsm.dashboard.commissioning import report_dirs
from edgedsm.dashboard.history import History
from edgedsm.dashboard.plant import Plant, RegionInfo
from edgedsm.dashboard.server import DashboardServer, EventHub
from edgedsm.dashboard.subscriber import PlantSubscriber
from edgedsm.publish.settings import MqttSettings
from edgedsm.validation import read_toml

log = logging.getLogger(__name__)

SHAPE_KEYS = {"shape", "x", "y", "width", "height", "cx", "cy", "radius", "inner_radius", "outer_radius", "points"}


@dataclass
class DashboardSettings:
    mqtt: MqttSettings
    listen: tuple[str, int]
    database: Path
    retention_s: float
    token: str | None
    daemon_configs: list[Path]
    access: AccessSettings = field(default_factory=AccessSettings)
    viewer_password: str | None = None


def regions_from_configs(paths: list[Path]) -> dict[str, dict[str, RegionInfo]]:
    """Region outlines and thresholds per device, read from daemon configs (the page draws them;
    the dashboard never writes a config). Shapes the page cannot draw (text, mask) keep their
    thresholds only."""
    found: dict[str, dict[str, RegionInfo]] = {}
    for path in paths:
        data = read_toml(path)
        device = data.get("device", {}).get("name", "camera1") if isinstance(data.get("device"), dict) else "camera1"
        regions: dict[str, RegionInfo] = {}
        stages = _stages(data.get("kinetics"))
        for entry in data.get("regions", []) if isinstance(data.get("regions"), list) else []:
            if not isinstance(entry, dict) or not isinstance(entry.get("name"), str):
                continue
            shape: dict[str, Any] = {key: value for key, value in entry.items() if key in SHAPE_KEYS}
            shape.setdefault("shape", "full")
            regions[entry["name"]] = RegionInfo(entry["name"], shape, _float(entry.get("wet_above")),
                                                _float(entry.get("dry_below")), stages)
        found[str(device)] = regions
    return found


def _stages(kinetics: Any) -> list[dict[str, Any]]:
    """The device's drying stages ([[kinetics.stages]], with [kinetics] enabled): each a name and a
    rate in Hz; an entry the page could not draw is left out (the daemon's own check refuses it)."""
    if not isinstance(kinetics, dict) or kinetics.get("enabled") is not True:
        return []
    stages = kinetics.get("stages") if isinstance(kinetics.get("stages"), list) else []
    return [{"name": stage["name"], "rate_below_hz": rate} for stage in stages
            if isinstance(stage, dict) and isinstance(stage.get("name"), str)
            and (rate := _float(stage.get("rate_below_hz"))) is not None and rate > 0]


def _float(value: Any) -> float | None:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def _warn_exposure(settings: DashboardSettings, *, tls_on: bool) -> None:
    """Say in the log what a listen address beyond this machine exposes."""
    host = settings.listen[0]
    try:
        loopback = ipaddress.ip_address(host).is_loopback
    except ValueError:
        loopback = host == "localhost"
    if loopback:
        return
    if not tls_on and (settings.viewer_password or settings.token):
        log.warning("dashboard: plain HTTP on %s: the viewer password, session cookie and command token travel "
                    "in clear (use --tls-cert/--tls-key or a TLS reverse proxy; docs/dashboard.md, Security)", host)
    if settings.viewer_password is None:
        log.warning("dashboard: listening on %s without a viewer login: anyone who reaches the port sees the "
                    "plant (set the credential dashboard-viewer-password; docs/dashboard.md, Security)", host)


class Dashboard:
    """``start()`` connects and serves; ``stop()`` undoes it."""

    def __init__(self, settings: DashboardSettings, *, password: str | None) -> None:
        self.settings = settings
        tls = tls_context(settings.access)
        login = None if settings.viewer_password is None else ViewerLogin(
            settings.viewer_password, secure=tls is not None, session_s=settings.access.session_hours * 3600)
        settings.database.parent.mkdir(parents=True, exist_ok=True)
        self.history = History(settings.database, settings.retention_s)
        self.hub = EventHub()
        self.plant = Plant(settings.mqtt.topic_prefix, self.history, self.hub.publish,
                           regions_from_configs(settings.daemon_configs))
        try:
            self.subscriber = PlantSubscriber(settings.mqtt, self.plant, password=password)
            self.server = DashboardServer(settings.listen, self.plant, self.history, self.hub, token=settings.token,
                                          send_command=self.subscriber.send_command,
                                          broker_connected=self.subscriber.connected.is_set,
                                          commissioning_dirs=report_dirs(settings.daemon_configs),
                                          limits=settings.access.limits, tls=tls,
                                          allowed_hosts=settings.access.allowed_hosts, login=login)
        except BaseException:
            self.history.close()
            raise
        _warn_exposure(settings, tls_on=tls is not None)

    @property
    def url(self) -> str:
        return self.server.url

    def start(self) -> Dashboard:
        self.subscriber.start()
        return self

    def serve_forever(self) -> None:
        self.server.serve_forever(poll_interval=0.5)

    def serve_in_background(self, connect_wait_s: float = 5.0) -> Dashboard:
        """Connect and serve from threads (the demo runs it beside the daemon); waits for the broker
        up to ``connect_wait_s`` so that the first alerts are seen."""
        self.start()
        self.subscriber.connected.wait(connect_wait_s)
        threading.Thread(target=self.serve_forever, name="dashboard-http", daemon=True).start()
        return self

    def stop(self) -> None:
        self.server.stop()
        self.subscriber.stop()
        self.history.close()
