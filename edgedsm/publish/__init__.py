"""Publishing over MQTT: the publisher, its settings, map encoding and the durable alert queue.

The daemon builds one :class:`MqttPublisher` from the ``[mqtt]`` table (:class:`MqttSettings`)
and its state directory; ``edgedsm watch`` and any other subscriber decode maps with
:func:`decode_map`. Topics and delivery guarantees are described in ``edgedsm.publish.mqtt``,
commands in ``edgedsm.publish.commands``.
"""

from __future__ import annotations

from edgedsm.publish.alertqueue import AlertQueue, QueuedAlert
from edgedsm.publish.commands import (
    COMMANDS,
    Command,
    DarkCommand,
    LaserCommand,
    PublishMapsCommand,
    RebaselineCommand,
)
from edgedsm.publish.errors import MapCodecError, PublishError
from edgedsm.publish.mapcodec import decode_map, downsample_map, encode_map
from edgedsm.publish.mqtt import CommandHandler, MqttPublisher, Topics, build_ssl_context
from edgedsm.publish.settings import (
    CREDENTIAL_NAME,
    PASSWORD_ENV,
    MqttSettings,
    MqttTlsSettings,
    resolve_password,
)

__all__ = [
    "COMMANDS",
    "CREDENTIAL_NAME",
    "PASSWORD_ENV",
    "AlertQueue",
    "Command",
    "CommandHandler",
    "DarkCommand",
    "LaserCommand",
    "MapCodecError",
    "MqttPublisher",
    "MqttSettings",
    "MqttTlsSettings",
    "PublishError",
    "PublishMapsCommand",
    "QueuedAlert",
    "RebaselineCommand",
    "Topics",
    "build_ssl_context",
    "decode_map",
    "downsample_map",
    "encode_map",
    "resolve_password",
]
