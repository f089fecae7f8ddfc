"""Publishing: the sinks, the MQTT link and its settings, map encoding and the alert store.

The daemon builds one :class:`MqttSink` from the ``[mqtt]`` table (:class:`MqttSettings`) and
its state directory; ``edgedsm watch`` and any other subscriber decode maps with
:func:`decode_map`. Topics and delivery guarantees are described in ``edgedsm.publish.mqtt``,
commands in ``edgedsm.publish.commands`` and ``edgedsm.publish.command_channel``.
"""

from __future__ import annotations

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
from edgedsm.publish.settings import (
    CREDENTIAL_NAME,
    PASSWORD_ENV,
    MqttSettings,
    MqttTlsSettings,
    resolve_password,
)
from edgedsm.publish.topics import Topics

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
