"""The subscriber behind ``edgedsm watch`` (and the demo): availability, state changes, alerts,
commands' replies, statistics and maps of one daemon, one line per event.

Payloads are parsed as the daemon's typed messages (``edgedsm.messages``); one that does not
parse is printed as "unreadable" with the reason. Alerts are deduplicated on (stream, seq).
"""

from __future__ import annotations

import json
import os
import threading
import time
from collections.abc import Callable
from datetime import datetime
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
from paho.mqtt.properties import Properties
from paho.mqtt.reasoncodes import ReasonCode
from pydantic import ValidationError

from edgedsm.imageio import save_map_png
from edgedsm.messages import Alert, AlertKind, StateReport, Stats
from edgedsm.publish.commands import CommandReply
from edgedsm.publish.connection import (
    build_ssl_context,
    connect_in_background,
    describe_refusal,
    diagnose,
    make_client,
)
from edgedsm.publish.errors import MapCodecError, PublishError
from edgedsm.publish.mapcodec import decode_map
from edgedsm.publish.settings import MqttSettings
from edgedsm.publish.topics import Topics

CONNECT_WAIT_S = 10.0
EXCERPT_CHARS = 80  # of an unreadable payload, shown beside the reason


def _now() -> str:
    return datetime.now().strftime("%Y-%m-%d %H:%M:%S.%f")[:-3]


def _clock(t: Any) -> str:
    try:
        return datetime.fromtimestamp(float(t)).strftime("%H:%M:%S")
    except (TypeError, ValueError, OverflowError, OSError):
        return "?"


def _number(value: Any) -> str:
    return f"{value:.4g}" if isinstance(value, int | float) and not isinstance(value, bool) else str(value)


class Watcher:
    """The subscriber behind ``edgedsm watch``; prints through ``emit`` (one line per event)."""

    def __init__(self, settings: MqttSettings, *, password: str | None, client_id: str | None = None,
                 save_maps: Path | None = None, show_stats: bool = False, count: int | None = None,
                 emit: Callable[[str], None] | None = None, json_lines: bool = False) -> None:
        self.settings = settings
        self.json_lines = json_lines
        self.topics = Topics.from_settings(settings)
        self.password = password
        self.save_maps = save_maps
        self.show_stats = show_stats
        self.count = count
        self.emit = emit or (lambda line: print(line, flush=True))
        self.alerts_seen: set[tuple[Any, Any]] = set()
        self.done = threading.Event()
        self.connected = threading.Event()
        self.refusal: str | None = None
        self._availability: str | None = None
        self.others: set[str] = set()  # other devices with an availability under the same prefix
        self._hinted = False
        self._states: dict[str, str] = {}
        self._metas: dict[str, dict[str, Any]] = {}
        self._pngs: dict[str, bytes] = {}
        self._ssl = build_ssl_context(settings.tls) if settings.tls is not None else None
        # MQTT 3.1.1 whatever the daemon speaks: clean_session=False is what a persistent
        # session needs there, and watch needs nothing of MQTT 5.
        self.client = make_client(
            settings, client_id=client_id or f"edgedsm-watch-{os.getpid()}-{time.monotonic_ns() % 10**6}",
            password=password, ssl_context=self._ssl, protocol="3.1.1", clean_session=client_id is None)
        self.client.on_connect = self._on_connect
        self.client.on_disconnect = self._on_disconnect
        self.client.on_message = self._on_message

    def start(self, wait_s: float = CONNECT_WAIT_S) -> None:
        """Connect (in paho's thread) and wait, bounded, for the broker's answer."""
        connect_in_background(self.client, self.settings)
        deadline = time.monotonic() + wait_s
        while not self.connected.wait(0.05):
            if self.refusal is not None:
                self.stop()
                raise PublishError(self.refusal)
            if time.monotonic() >= deadline:
                why = diagnose(self.settings, self._ssl)
                self.stop()
                raise PublishError(f"no connection to the MQTT broker within {wait_s:g} s: {why}")

    def stop(self) -> None:
        self.done.set()  # our own disconnect is not a lost connection
        self.client.disconnect()
        stopper = threading.Thread(target=self.client.loop_stop, daemon=True)
        stopper.start()
        stopper.join(timeout=2.0)

    @property
    def _all_availability(self) -> str:
        return f"{self.topics.prefix}/+/availability"

    def hint_if_silent(self) -> None:
        """Once: say so when no daemon ever published on this base, and which devices did."""
        if self._hinted or self._availability is not None or not self.connected.is_set():
            return
        self._hinted = True
        seen = ", ".join(sorted(self.others)) or "none"
        self._event("silence", f"no daemon has published on {self.topics.base} (no availability); devices "
                               f"seen under {self.topics.prefix}/: {seen}", label="connection",
                    base=self.topics.base, devices=sorted(self.others))

    def _event(self, kind: str, text: str, *, label: str | None = None, **data: Any) -> None:
        """One line: ``<time>  <label>  <text>``, or with ``json_lines`` one JSON object
        (``time``: UTC epoch s of arrival, ``event``: the kind, then the event's own fields)."""
        if self.json_lines:
            self.emit(json.dumps({"time": time.time(), "event": kind, **data}, default=str))
        else:
            self.emit(f"{_now()}  {label or kind:<13} {text}")

    # -- callbacks (paho's thread) --------------------------------------------------------------

    def _on_connect(self, client: mqtt.Client, userdata: Any, flags: Any, reason: ReasonCode,
                    properties: Properties | None) -> None:
        if reason.is_failure:
            self.refusal = describe_refusal(reason, self.settings, self.password is not None)
            return
        topics = [self.topics.availability, self.topics.state, self.topics.alerts, self.topics.replies_filter,
                  self._all_availability]
        if self.show_stats:
            topics.append(self.topics.stats)
        if self.save_maps is not None:
            topics += [self.topics.maps_filter, f"{self.topics.maps_filter}/meta"]
        client.subscribe([(topic, 1) for topic in topics])
        if self.connected.is_set() or getattr(flags, "session_present", False):
            self._event("connection", f"re-established to {self.settings.host}:{self.settings.port}",
                        status="re-established", broker=f"{self.settings.host}:{self.settings.port}",
                        base=self.topics.base)
        else:
            self._event("connection", f"{self.settings.host}:{self.settings.port}, watching {self.topics.base}",
                        status="connected", broker=f"{self.settings.host}:{self.settings.port}",
                        base=self.topics.base)
        self.connected.set()

    def _on_disconnect(self, client: mqtt.Client, userdata: Any, flags: Any, reason: ReasonCode,
                       properties: Properties | None) -> None:
        if self.connected.is_set() and not self.done.is_set():
            self._event("connection", f"lost ({reason}); reconnecting", status="lost", reason=str(reason))

    def _on_message(self, client: mqtt.Client, userdata: Any, message: mqtt.MQTTMessage) -> None:
        topic = message.topic
        try:
            if topic == self.topics.availability:
                self._availability_message(message.payload.decode("utf-8", "replace"), message.retain)
            elif mqtt.topic_matches_sub(self._all_availability, topic):
                self.others.add(topic[len(self.topics.prefix) + 1:-len("/availability")])
            elif topic == self.topics.state:
                self._state_message(StateReport.model_validate_json(message.payload))
            elif topic == self.topics.alerts:
                self._alert_message(Alert.model_validate_json(message.payload))
            elif topic == self.topics.stats:
                self._stats_message(Stats.model_validate_json(message.payload))
            elif topic.endswith("/reply"):
                self._reply_message(CommandReply.model_validate_json(message.payload))
            elif topic.startswith(f"{self.topics.base}/map/"):
                self._map_message(topic[len(self.topics.base) + 5:], message.payload)
        except ValidationError as exc:
            self._unreadable(topic, message.payload, _validation_reason(exc))
        except (ValueError, UnicodeDecodeError, OSError) as exc:
            self._unreadable(topic, message.payload, str(exc))

    def _unreadable(self, topic: str, payload: bytes, reason: str) -> None:
        excerpt = payload[:EXCERPT_CHARS].decode("utf-8", "replace")
        more = "..." if len(payload) > EXCERPT_CHARS else ""
        self._event("unreadable", f"{topic}: {reason}: {excerpt!r}{more}", topic=topic, reason=reason)

    # -- one handler per kind of message --------------------------------------------------------

    def _availability_message(self, value: str, retained: bool) -> None:
        if value != self._availability:
            self._availability = value
            self._event("availability", f"{value}{' (retained)' if retained else ''}", value=value,
                        retained=retained)

    def _state_message(self, report: StateReport) -> None:
        for name, region in report.regions.items():
            previous = self._states.get(name)
            if region.state == previous:
                continue
            self._states[name] = region.state
            notes = ([f"activity {_number(region.activity)}"] if region.activity is not None else []) + (
                [f"signal {region.signal}"] if region.signal not in (None, "ok") else [])
            detail = f" ({', '.join(notes)})" if notes else ""
            change = f"{previous} -> {region.state}" if previous is not None else region.state
            self._event("state", f"{name}: {change}{detail}", **{"from": previous}, **region.to_json())

    def _alert_message(self, alert: Alert) -> None:
        key = (alert.stream, alert.seq)
        if alert.seq is not None and key in self.alerts_seen:
            return  # a resend after a reconnection: already shown
        self.alerts_seen.add(key)
        parts = [f"{alert.region or 'device'}:"]
        if alert.kind == AlertKind.TRANSITION or alert.from_state or alert.to_state:
            parts.append(f"{alert.from_state} -> {alert.to_state}")
        if alert.activity is not None:
            parts.append(f"(activity {_number(alert.activity)})")
        parts += [f"[{alert.kind}]", f"at {_clock(alert.t)}"]
        if alert.reason:
            parts.append(f"- {alert.reason}")
        label = f"alert #{alert.seq if alert.seq is not None else '?'}"
        self._event("alert", " ".join(parts), label=label, alert=alert.to_json())
        if self.count is not None and len(self.alerts_seen) >= self.count:
            self.done.set()

    def _stats_message(self, stats: Stats) -> None:
        parts = [f"frames {stats.frames}", f"{_number(stats.fps)} fps", f"laser {stats.laser}",
                 "ready" if stats.ready else "filling"]
        parts += [f"{region} {state}" for region, state in stats.states.items()]
        if stats.warning:
            parts.append(f"warning: {stats.warning}")
        if stats.mqtt and stats.mqtt.get("storage_error"):
            parts.append(f"storage: {stats.mqtt['storage_error']}")
        self._event("stats", ", ".join(parts), stats=stats.to_json())

    def _reply_message(self, reply: CommandReply) -> None:
        outcome = "ok" if reply.ok else f"refused: {reply.error}"
        rid = f" (request {reply.request_id})" if reply.request_id is not None else ""
        self._event("command", f"{reply.command}: {outcome}{rid}", reply=reply.model_dump(mode="json"))

    def _map_message(self, rest: str, payload: bytes) -> None:
        if self.save_maps is None:
            return
        if rest.endswith("/meta"):
            name = rest[:-5]
            meta = json.loads(payload)
            if not isinstance(meta, dict):
                raise ValueError(f"map meta must be a JSON object, got {type(meta).__name__}")
            self._metas[name] = meta
        else:
            name = rest
            self._pngs[name] = payload
        meta, png = self._metas.get(name), self._pngs.get(name)
        if meta is None or png is None:
            return
        try:
            values = decode_map(png, meta)
        except MapCodecError as exc:
            if "CRC" in str(exc):
                return  # PNG and meta of different updates: wait for the partner
            self._event("map", f"not decoded: {exc}", label=f"map {name:<9}", name=name, error=str(exc))
            self._metas.pop(name, None)
            self._pngs.pop(name, None)
            return
        del self._metas[name], self._pngs[name]
        seq = meta.get("seq")
        stem = f"{name}-{seq:010d}" if isinstance(seq, int) else f"{name}-{int(time.time() * 1000)}"
        path = self.save_maps / f"{stem}.png"
        title = f"{name.upper()} seq {seq}" if seq is not None else name.upper()
        save_map_png(path, values, title=title)
        self._event("map", f"#{seq} {values.shape[0]}x{values.shape[1]} "
                    f"[{_number(meta.get('min'))}, {_number(meta.get('max'))}] saved to {path}",
                    label=f"map {name:<9}", name=name, seq=seq, shape=list(values.shape), path=str(path))


def _validation_reason(exc: ValidationError) -> str:
    """The first problem of a payload that does not parse, in one phrase."""
    error = exc.errors()[0]
    where = ".".join(str(part) for part in error["loc"]) or "payload"
    return f"not a valid {exc.title}: {where}: {error['msg']}"
