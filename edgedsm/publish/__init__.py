"""Publishing: the sinks, the MQTT link and its settings, map encoding and the alert store.

The daemon builds one :class:`MqttSink` from the ``[mqtt]`` table (:class:`MqttSettings`) and
its state directory; ``edgedsm watch`` and any other subscriber decode maps with
:func:`decode_map`. Topics and delivery guarantees are described in ``edgedsm.publish.mqtt``,
commands in ``edgedsm.publish.commands`` and ``edgedsm.publish.command_channel``; one MQTT
connection's life cycle in ``edgedsm.publish.session``.

The names below are loaded on first use (PEP 562): reading a config needs the settings, not
paho, OpenCV or sqlite.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

#: Each public name and the submodule that defines it.
_SOURCES: dict[str, str] = {
    "AlertQueue": "alertqueue",
    "QueuedAlert": "alertqueue",
    "AlertStore": "alertstore",
    "CommandHandler": "command_channel",
    "COMMANDS": "commands",
    "Command": "commands",
    "DarkCommand": "commands",
    "LaserCommand": "commands",
    "PublishMapsCommand": "commands",
    "RebaselineCommand": "commands",
    "build_ssl_context": "connection",
    "MapCodecError": "errors",
    "PublishError": "errors",
    "StorageError": "errors",
    "MqttSink": "json_sink",
    "decode_map": "mapcodec",
    "downsample_map": "mapcodec",
    "encode_map": "mapcodec",
    "MqttPublisher": "mqtt",
    "MqttSession": "session",
    "CREDENTIAL_NAME": "settings",
    "PASSWORD_ENV": "settings",
    "MqttSettings": "settings",
    "MqttTlsSettings": "settings",
    "resolve_password": "settings",
    "Topics": "topics",
}

__all__ = [
    "COMMANDS",
    "CREDENTIAL_NAME",
    "PASSWORD_ENV",
    "AlertQueue",
    "AlertStore",
    "Command",
    "CommandHandler",
    "DarkCommand",
    "LaserCommand",
    "MapCodecError",
    "MqttPublisher",
    "MqttSession",
    "MqttSettings",
    "MqttSink",
    "MqttTlsSettings",
    "PublishError",
    "PublishMapsCommand",
    "QueuedAlert",
    "RebaselineCommand",
    "StorageError",
    "Topics",
    "build_ssl_context",
    "decode_map",
    "downsample_map",
    "encode_map",
    "resolve_password",
]


def __getattr__(name: str) -> Any:
    module = _SOURCES.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value  # looked up once
    return value


if TYPE_CHECKING:
    from edgedsm.publish.alertqueue import AlertQueue, QueuedAlert
    from edgedsm.publish.alertstore import AlertStore
    from edgedsm.publish.command_channel import CommandHandler
    from edgedsm.publish.commands import (
        COMMANDS,
        Command,
        DarkCommand,
        LaserCommand,
        PublishMapsCommand,
        RebaselineCommand,
    )
    from edgedsm.publish.connection import build_ssl_context
    from edgedsm.publish.errors import MapCodecError, PublishError, StorageError
    from edgedsm.publish.json_sink import MqttSink
    from edgedsm.publish.mapcodec import decode_map, downsample_map, encode_map
    from edgedsm.publish.mqtt import MqttPublisher
    from edgedsm.publish.session import MqttSession
    from edgedsm.publish.settings import (
        CREDENTIAL_NAME,
        PASSWORD_ENV,
        MqttSettings,
        MqttTlsSettings,
        resolve_password,
    )
    from edgedsm.publish.topics import Topics
