"""The dashboard's MQTT link: subscribes to ``<prefix>/+/#`` and hands every message to the plant;
sends the few commands the page may send (never ``laser``), signed with the dashboard's command
key (``edgedsm.publish.command_auth``; found as the daemon finds its own: ``$EDGEDSM_COMMAND_KEY``,
``[mqtt] command_key_file``, the credential ``command-key``; the first key of the file signs)."""

from __future__ import annotations

import json
import logging
import threading
import time
import uuid
from collections.abc import Mapping
from typing import Any

import paho.mqtt.client as mqtt
from paho.mqtt.reasoncodes import ReasonCode

from edgedsm.dashboard.plant import Plant
from edgedsm.publish.command_auth import sign, signing_key
from edgedsm.publish.commands import COMMANDS
from edgedsm.publish.connection import build_ssl_context, connect_in_background, describe_refusal, make_client
from edgedsm.publish.settings import MqttSettings, resolve_command_keys
from edgedsm.publish.topics import Topics

log = logging.getLogger(__name__)

#: Commands the page may send; the laser is never switched from the dashboard.
ALLOWED_COMMANDS = ("rebaseline", "dark", "publish_maps")


class PlantSubscriber:
    """One paho client for the whole plant. ``command_keys``: overrides :func:`resolve_command_keys`."""

    def __init__(self, settings: MqttSettings, plant: Plant, *, password: str | None,
                 command_keys: Mapping[str, bytes] | None = None) -> None:
        self.settings = settings
        keys = resolve_command_keys(settings) if command_keys is None else command_keys
        self._key = signing_key(keys) if keys else None  # (key id, secret)
        self.plant = plant
        self.connected = threading.Event()
        self.client = make_client(settings, client_id=f"edgedsm-dashboard-{uuid.uuid4().hex[:8]}", password=password,
                                  ssl_context=build_ssl_context(settings.tls) if settings.tls else None)
        self.client.on_connect = self._on_connect
        self.client.on_disconnect = self._on_disconnect
        self.client.on_message = self._on_message
        self._password_given = password is not None

    @property
    def subscription(self) -> str:
        return f"{self.settings.topic_prefix.strip('/')}/+/#"

    def start(self) -> None:
        connect_in_background(self.client, self.settings)

    def stop(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()

    def send_command(self, device: str, name: str) -> None:
        """Publish a command (QoS 1, not retained), signed; ``ValueError`` for one the page may not
        send, or one that needs a signature when the dashboard has no command key."""
        if name not in ALLOWED_COMMANDS:
            raise ValueError(f"command {name!r} is not allowed from the dashboard")
        topic = Topics.of(self.settings.topic_prefix, device).command(name)
        payload: dict[str, Any] = {}
        if self._key is not None:
            payload = sign(*self._key, topic, payload, now=time.time())
        elif COMMANDS[name].requires_authorisation:
            raise ValueError(f"the dashboard has no command key, so the daemon would refuse {name!r} "
                             f"(docs/security.md)")
        payload["request_id"] = f"dashboard-{uuid.uuid4().hex[:8]}"
        self.client.publish(topic, json.dumps(payload), qos=1, retain=False)

    def _on_connect(self, client: mqtt.Client, userdata: Any, flags: Any, reason: ReasonCode, props: Any) -> None:
        if reason.is_failure:
            log.error("dashboard: %s", describe_refusal(reason, self.settings, self._password_given))
            return
        client.subscribe(self.subscription, qos=1)
        self.connected.set()
        log.info("dashboard: connected to %s:%d, subscribed to %s", self.settings.host, self.settings.port,
                 self.subscription)

    def _on_disconnect(self, client: mqtt.Client, userdata: Any, flags: Any, reason: ReasonCode,
                       props: Any) -> None:
        self.connected.clear()

    def _on_message(self, client: mqtt.Client, userdata: Any, message: mqtt.MQTTMessage) -> None:
        try:
            self.plant.handle(message.topic, message.payload)
        except Exception:  # a bug must not kill paho's network thread; bad input is handled in Plant
            log.exception("dashboard: message on %s not handled", message.topic)
