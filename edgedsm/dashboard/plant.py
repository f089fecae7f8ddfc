"""The plant as the dashboard sees it: every device heard on ``<prefix>/+/#``, its availability,
states, statistics, alerts and latest maps, parsed from the daemons' typed messages.

Everything from MQTT is untrusted: payloads are size-checked before parsing, parsed with the
daemon's own pydantic types, and a payload that does not parse is counted and described (one
line) on its device, never raised. The page escapes every string (it only uses ``textContent``).
"""

from __future__ import annotations

import json
import logging
import struct
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np
from pydantic import ValidationError

from edgedsm.dashboard import maps
from edgedsm.dashboard.history import AlertRow, History, Sample
from edgedsm.messages import Alert, StateReport, Stats
from edgedsm.publish import units
from edgedsm.publish.errors import MapCodecError
from edgedsm.publish.mapcodec import decode_map

log = logging.getLogger(__name__)

MAX_DEVICES = 256
MAX_NAME_CHARS = 128  # device, region and map names longer than this are refused
MAX_JSON_BYTES = 256 * 1024
MAX_MAP_BYTES = 4 * 1024 * 1024  # a 4096² 16-bit PNG of a smooth map is far smaller
MAX_MAP_SIDE = 4096
MAX_MAPS = 8  # map names kept per device
MAX_REGIONS = 64
ALERTS_KEPT = 50
SEEN_ALERTS_KEPT = 2000

M = TypeVar("M", StateReport, Stats, Alert)
Emit = Callable[[str, dict[str, Any]], None]


@dataclass
class RegionInfo:
    """What the daemon's config says about a region (outline and thresholds), when known."""

    name: str
    shape: dict[str, Any]
    wet_above: float | None = None
    dry_below: float | None = None
    # the device's [[kinetics.stages]] ([kinetics] on): {"name", "rate_below_hz"}, drawn on the kinetics curve
    stages: list[dict[str, Any]] = field(default_factory=list)


@dataclass
class MapImage:
    values: np.ndarray
    meta: dict[str, Any]
    png: bytes


@dataclass
class Device:
    name: str
    availability: str | None = None
    last_seen: float = 0.0
    state: dict[str, Any] | None = None
    stats: dict[str, Any] | None = None
    alerts: deque[dict[str, Any]] = field(default_factory=lambda: deque(maxlen=ALERTS_KEPT))
    seen: deque[tuple[str | None, int]] = field(default_factory=lambda: deque(maxlen=SEEN_ALERTS_KEPT))
    maps: dict[str, MapImage] = field(default_factory=dict)
    pending_meta: dict[str, dict[str, Any]] = field(default_factory=dict)
    pending_png: dict[str, bytes] = field(default_factory=dict)
    rejected: int = 0
    last_rejection: str | None = None
    regions: dict[str, RegionInfo] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        """What the page shows (JSON-ready; strings are escaped by the page)."""
        return {"device": self.name, "availability": self.availability, "last_seen": self.last_seen,
                "state": self.state, "stats": self.stats, "rejected": self.rejected,
                "last_rejection": self.last_rejection,
                "maps": {name: _map_info(image) for name, image in self.maps.items()},
                "regions": {name: info.__dict__ for name, info in self.regions.items()}}


def _map_info(image: MapImage) -> dict[str, Any]:
    keys = ("seq", "t", "min", "max", "shape", "source_shape", "estimator", "window", "lag")
    return {key: image.meta.get(key) for key in keys}


class Rejected(ValueError):
    """A payload the dashboard does not accept (the message is the one-line reason)."""


class Plant:
    """Routes ``<prefix>/<device>/<rest>`` messages into per-device views and the history."""

    def __init__(self, prefix: str, history: History | None, emit: Emit,
                 configured_regions: dict[str, dict[str, RegionInfo]] | None = None,
                 clock: Callable[[], float] = time.time) -> None:
        self.prefix = prefix.strip("/")
        self.history = history
        self.emit = emit
        self.configured = configured_regions or {}
        self.clock = clock
        self.devices: dict[str, Device] = {}
        self.ignored = 0  # messages of devices beyond MAX_DEVICES, or with unusable topics
        self.lock = threading.Lock()

    # -- reading (HTTP threads) -------------------------------------------------------------

    def snapshot(self) -> list[dict[str, Any]]:
        with self.lock:
            return [{**device.summary(), "alerts": list(device.alerts)}
                    for device in sorted(self.devices.values(), key=lambda d: d.name)]

    def map_image(self, device: str, name: str) -> MapImage | None:
        with self.lock:
            found = self.devices.get(device)
            return None if found is None else found.maps.get(name)

    def region_info(self, device: str, region: str) -> RegionInfo | None:
        with self.lock:
            found = self.devices.get(device)
            return None if found is None else found.regions.get(region)

    # -- writing (the MQTT thread) ----------------------------------------------------------

    def handle(self, topic: str, payload: bytes) -> None:
        """One MQTT message; never raises on bad input."""
        head, _, rest = topic.partition(f"{self.prefix}/")
        device_name, _, kind = rest.partition("/")
        if head or not device_name or not kind or len(device_name) > MAX_NAME_CHARS or kind.startswith("cmd/"):
            return  # not a device topic (or a command/reply, not the dashboard's business)
        with self.lock:
            device = self._device(device_name)
            if device is None:
                self.ignored += 1
                return
            device.last_seen = self.clock()
            try:
                event = self._route(device, kind, payload)
            except Rejected as exc:
                device.rejected += 1
                device.last_rejection = f"{kind}: {exc}"[:300]
                log.info("dashboard: %s/%s: %s", device_name, kind, exc)
                event = ("device", device.summary())
        if event is not None:
            self.emit(*event)

    def _device(self, name: str) -> Device | None:
        device = self.devices.get(name)
        if device is None:
            if len(self.devices) >= MAX_DEVICES:
                return None
            device = self.devices[name] = Device(name, regions=dict(self.configured.get(name, {})))
        return device

    def _route(self, device: Device, kind: str, payload: bytes) -> tuple[str, dict[str, Any]] | None:
        if kind == "availability":
            text = payload[:16].decode("utf-8", "replace")
            if text not in ("online", "offline"):
                raise Rejected(f"availability must be online or offline, got {text[:16]!r}")
            device.availability = text
        elif kind == "state":
            report = _parse(StateReport, payload)
            if len(report.regions) > MAX_REGIONS:
                raise Rejected(f"{len(report.regions)} regions (at most {MAX_REGIONS} are shown)")
            device.state = report.to_json()
        elif kind == "stats":
            self._stats(device, _parse(Stats, payload))
        elif kind == "alerts":
            return self._alert(device, _parse(Alert, payload))
        elif kind.startswith("map/"):
            return self._map(device, kind[4:], payload)
        else:
            return None  # a topic of a newer daemon: ignored
        return "device", device.summary()

    def _stats(self, device: Device, stats: Stats) -> None:
        if max(len(stats.regions), len(stats.states), len(stats.signal), len(stats.kinetics)) > MAX_REGIONS:
            raise Rejected(f"more than {MAX_REGIONS} regions")
        # the plain region mean of the judged map, shown beside the judged value under its own name
        plain = {name: per_map[stats.estimator].mean if stats.estimator in per_map else None
                 for name, per_map in stats.regions.items()}
        activity, judged = _judged(device, stats)
        device.stats = {"t": stats.t, "fps": stats.fps, "frames": stats.frames, "ready": stats.ready,
                        "laser": stats.laser, "estimator": stats.estimator, "drops": stats.drops,
                        "ambient_level": stats.ambient_level, "warning": stats.warning,
                        # what the thresholds judge (the chart draws it against them), with its unit
                        "activity": activity, "judged": judged, "plain": plain,
                        "plain_label": f"{units.label_of(stats.estimator)} mean",
                        "states": dict(stats.states),
                        # each region's decorrelation time, rate and status ([kinetics] on; a status, never a
                        # number, where there is none) and the drying stages it reached
                        "kinetics": {name: reading.to_json() for name, reading in stats.kinetics.items()},
                        # each region's signal quality and activity above the noise (estimator.noise_floor)
                        "signal": {name: signal.to_json() for name, signal in stats.signal.items()}}
        if self.history is not None:
            for region in set(activity) | set(stats.states) | set(stats.kinetics):
                reading = stats.kinetics.get(region)
                self.history.add(Sample(device.name, region, stats.t, activity.get(region), stats.states.get(region),
                                        *(() if reading is None else (reading.tau_s, reading.status, reading.bound_s))))

    def _alert(self, device: Device, alert: Alert) -> tuple[str, dict[str, Any]] | None:
        if alert.seq is not None:
            key = (alert.stream, alert.seq)
            if key in device.seen:
                return None  # at-least-once delivery: a resend
            device.seen.append(key)
        row = alert.to_json()
        device.alerts.append(row)
        if self.history is not None:
            self.history.add(AlertRow(device.name, alert.t, str(alert.kind), alert.region, alert.from_state,
                                      alert.to_state, alert.reason, alert.activity, alert.stream, alert.seq))
        return "alert", {"device": device.name, "alert": row}

    def _map(self, device: Device, rest: str, payload: bytes) -> tuple[str, dict[str, Any]] | None:
        name, _, suffix = rest.partition("/")
        if suffix == "color" and name and len(name) <= 32:
            return None  # the 8-bit picture for viewers ([homeassistant]): the page draws its own from the map
        if not name or len(name) > 32 or suffix not in ("", "meta"):
            raise Rejected("not a map topic")
        if name not in device.maps and len(device.maps) >= MAX_MAPS:
            raise Rejected(f"more than {MAX_MAPS} maps")
        if suffix == "meta":
            meta = _json_object(payload)
            device.pending_meta[name] = meta
        else:
            if len(payload) > MAX_MAP_BYTES:
                device.pending_png.pop(name, None)
                raise Rejected(f"map picture of {len(payload)} bytes (at most {MAX_MAP_BYTES})")
            _check_png_size(payload)
            device.pending_png[name] = payload
        meta, png = device.pending_meta.get(name), device.pending_png.get(name)
        if meta is None or png is None:
            return None
        try:
            values = decode_map(png, meta)
        except (MapCodecError, ValueError, TypeError, KeyError) as exc:
            if "CRC" in str(exc):
                return None  # picture and meta of different updates (QoS 0 may lose one): wait for the partner
            device.pending_png.pop(name, None)
            raise Rejected(f"map not decoded: {exc}") from None
        del device.pending_meta[name], device.pending_png[name]
        # float32 for the editor's statistics: half the memory, far finer than the PNG's 16-bit steps
        device.maps[name] = MapImage(values.astype(np.float32), meta, maps.colour_png(values))
        return "map", {"device": device.name, "map": name, **_map_info(device.maps[name])}


def _judged(device: Device, stats: Stats) -> tuple[dict[str, float | None], dict[str, dict[str, Any]]]:
    """Each region's judged activity and what it is (estimator, unit, label, basis). From the
    stats' ``activity``; a daemon older than it: the latest state report's ``activity`` (judged
    too), else nothing (the plain mean is never drawn against the thresholds)."""
    if stats.activity:
        return ({name: judged.value for name, judged in stats.activity.items()},
                {name: {"estimator": judged.estimator, "unit": units.display_unit(judged.unit),
                        "label": units.label_of(judged.estimator), "basis": judged.basis}
                 for name, judged in stats.activity.items()})
    regions = (device.state or {}).get("regions") or {}
    activity: dict[str, float | None] = {}
    judged: dict[str, dict[str, Any]] = {}
    for name, region in regions.items():
        if isinstance(region, dict) and name in stats.states:
            estimator = region.get("estimator") or stats.estimator
            value = region.get("activity")
            activity[name] = value if isinstance(value, int | float) else None
            judged[name] = {"estimator": estimator, "unit": units.display_unit(units.unit_of(estimator)),
                            "label": units.label_of(estimator), "basis": "state report"}
    return activity, judged


def _parse(model: type[M], payload: bytes) -> M:
    if len(payload) > MAX_JSON_BYTES:
        raise Rejected(f"payload of {len(payload)} bytes (at most {MAX_JSON_BYTES})")
    try:
        return model.model_validate_json(payload)
    except ValidationError as exc:
        error = exc.errors()[0]
        where = ".".join(str(part) for part in error["loc"]) or "payload"
        raise Rejected(f"not a valid {model.__name__}: {where}: {error['msg']}"[:200]) from None


def _json_object(payload: bytes) -> dict[str, Any]:
    if len(payload) > MAX_JSON_BYTES:
        raise Rejected(f"payload of {len(payload)} bytes (at most {MAX_JSON_BYTES})")
    try:
        data = json.loads(payload)
    except (ValueError, UnicodeDecodeError) as exc:
        raise Rejected(f"not JSON: {exc}"[:200]) from None
    if not isinstance(data, dict):
        raise Rejected(f"must be a JSON object, got {type(data).__name__}")
    return data


def _check_png_size(png: bytes) -> None:
    """Refuse pictures whose header claims more pixels than a map has (decoding would allocate them)."""
    if len(png) < 24 or png[:8] != b"\x89PNG\r\n\x1a\n" or png[12:16] != b"IHDR":
        raise Rejected("map picture is not a PNG")
    width, height = struct.unpack(">II", png[16:24])
    if not (0 < width <= MAX_MAP_SIDE and 0 < height <= MAX_MAP_SIDE):
        raise Rejected(f"map picture of {width}x{height} pixels (at most {MAX_MAP_SIDE} per side)")
