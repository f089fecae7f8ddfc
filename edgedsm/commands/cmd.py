"""Send one command to a running daemon over MQTT and wait for its reply (for scripts).

The command goes to ``<prefix>/<device>/cmd/NAME`` with a fresh ``request_id``; the reply with
that id on ``<prefix>/<device>/cmd/NAME/reply`` decides the exit status:

  0   the daemon accepted and carried out the command
  1   the daemon refused it (the reason is printed)
  2   no reply: within --timeout (daemon not running, wrong --device, broker dropped it), or
      at once when the daemon's retained availability says offline (it stopped)
  69  the broker cannot be reached (down, wrong host or port, TLS handshake failed)
  78  the broker refused the connection (user name, password, certificate or ACL)

Commands (docs/mqtt.md): laser {"state": "on"|"off"|"auto"}, rebaseline, dark, publish_maps,
record {"seconds": S} (a clip, with [recording]).

Examples:
  edgedsm cmd publish_maps -c /etc/edgedsm/line3.toml
  edgedsm cmd laser --device line3 --broker broker.local:1883 --args '{"state": "off"}'
  edgedsm cmd rebaseline --device line3 --json      # the reply as JSON on stdout
  edgedsm cmd record -c /etc/edgedsm/line3.toml --args '{"seconds": 30}'

Connection settings come from the config's [mqtt] table (-c) and/or the options; options win.
The password comes from $EDGEDSM_MQTT_PASSWORD (or $CREDENTIALS_DIRECTORY/mqtt-password).

Every command but publish_maps is signed with a command key (docs/security.md): from
--command-key-file, else $EDGEDSM_COMMAND_KEY, else the config's [mqtt] command_key_file, else
$CREDENTIALS_DIRECTORY/command-key; the first key of the file unless --key-id names another.
Without a key they are sent unsigned and the daemon refuses them.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time
import uuid
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
from pydantic import ValidationError

from edgedsm import _json
from edgedsm.commands.broker_options import add_credential_options, host_port, mqtt_settings, seconds
from edgedsm.errors import ConfigError, DataError
from edgedsm.publish.command_auth import sign, signing_key
from edgedsm.publish.commands import COMMANDS, CommandReply
from edgedsm.publish.connection import (
    build_ssl_context,
    connect_in_background,
    describe_refusal,
    diagnose,
    make_client,
)
from edgedsm.publish.errors import PublishError
from edgedsm.publish.settings import MqttSettings, resolve_command_keys, resolve_password
from edgedsm.publish.topics import Topics

NAME = "cmd"
HELP = ("send a command to a running daemon and wait for its reply (exit 0 accepted, 1 refused, 2 no reply or "
        "offline, 69 broker unreachable, 78 broker refused the credentials)")

EXIT_REFUSED = 1
EXIT_NO_REPLY = 2
CONNECT_WAIT_S = 10.0


class BrokerUnreachable(PublishError):
    """No connection to the broker (exit 69, EX_UNAVAILABLE: try again later)."""

    exit_code = 69
    kind = "broker unreachable"


class BrokerRefused(PublishError):
    """The broker refused the connection: credentials, certificate, ACL (exit 78: fix the settings)."""

    exit_code = 78
    kind = "broker refused"


class Offline(Exception):
    """The daemon's retained availability says ``offline``: nobody will answer."""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name", metavar="NAME", help="command: laser, rebaseline, dark, publish_maps, record")
    parser.add_argument("--args", default="{}", metavar="JSON", help="the command's arguments as a JSON object")
    parser.add_argument("-c", "--config", type=Path, metavar="CONFIG",
                        help="take the broker and device from this daemon config")
    parser.add_argument("--broker", type=host_port(), metavar="HOST:PORT", help="broker (default localhost:1883)")
    parser.add_argument("--prefix", dest="topic_prefix", metavar="PREFIX", help="topic prefix (default edgedsm)")
    parser.add_argument("--device", help="device name in the topics (default: the config's, else camera1)")
    parser.add_argument("--timeout", type=seconds, default=10.0, metavar="S",
                        help="longest wait for the reply (default 10)")
    parser.add_argument("--json", action="store_true", help="print the reply as one JSON object")
    parser.add_argument("--command-key-file", type=Path, metavar="FILE",
                        help="the command key(s) to sign with ('KEY_ID SECRET' lines); "
                             "default: as the daemon finds its own")
    parser.add_argument("--key-id", metavar="ID", help="which key of the file signs (default: the first)")
    add_credential_options(parser.add_argument_group("credentials and TLS (as the daemon's [mqtt])"))


def settings_of(args: argparse.Namespace) -> MqttSettings:
    """Broker settings as ``edgedsm watch`` builds them (config, then options)."""
    host, port = args.broker if args.broker is not None else (None, None)
    return mqtt_settings(args.config, args, {"host": host, "port": port, "topic_prefix": args.topic_prefix,
                                             "device": args.device,
                                             "command_key_file": getattr(args, "command_key_file", None)})


def parse_arguments(text: str) -> dict[str, Any]:
    """``--args``: a JSON object (DataError saying why not)."""
    try:
        value = json.loads(text)
    except ValueError as exc:
        raise DataError(f"--args is not JSON: {exc}") from None
    if not isinstance(value, dict):
        raise DataError(f"--args must be a JSON object, got {type(value).__name__}")
    if "request_id" in value:
        raise DataError("--args: request_id is set by edgedsm cmd")
    return value


def signed(topic: str, name: str, arguments: dict[str, Any], keys: Mapping[str, bytes],
           key_id: str | None) -> dict[str, Any]:
    """The payload of ``name`` for ``topic``: signed when it needs to be or when a key is at hand."""
    command = COMMANDS.get(name)
    if not keys:
        return dict(arguments)  # the daemon will say why it refuses (read-only, or not signed)
    if command is not None and not command.requires_authorisation and key_id is None:
        return dict(arguments)
    try:
        chosen, key = signing_key(keys, key_id)
    except KeyError as exc:
        raise ConfigError(f"--key-id: {exc.args[0]}") from None
    try:
        return sign(chosen, key, topic, arguments, now=time.time())
    except ValueError as exc:
        raise DataError(f"--args: {exc}") from None


def send(settings: MqttSettings, name: str, arguments: dict[str, Any], timeout_s: float,
         password: str | None = None, keys: Mapping[str, bytes] | None = None,
         key_id: str | None = None) -> CommandReply | None:
    """Publish the command (signed with ``keys``, default :func:`resolve_command_keys`) and wait
    for the reply carrying its request id (None: no reply in time). :class:`Offline` at once
    when the daemon's retained availability says ``offline`` (before the command is sent when
    the broker hands it over first, as mosquitto does); :class:`BrokerUnreachable` or
    :class:`BrokerRefused` when there is no connection."""
    topics = Topics.from_settings(settings)
    payload = signed(topics.command(name), name, arguments,
                     resolve_command_keys(settings) if keys is None else keys, key_id)
    request_id = f"cli-{uuid.uuid4().hex[:12]}"
    reply_topic = topics.reply(name)
    subscribed, answered = threading.Event(), threading.Event()
    found: list[CommandReply] = []
    refusal: list[str] = []
    failed: list[str] = []
    offline: list[bool] = []
    ssl_context = build_ssl_context(settings.tls) if settings.tls else None
    client = make_client(settings, client_id=f"edgedsm-cmd-{os.getpid()}-{uuid.uuid4().hex[:6]}",
                         password=password, ssl_context=ssl_context, protocol="3.1.1")
    subscriptions: dict[int, str] = {}

    def on_connect(client: mqtt.Client, userdata: Any, flags: Any, reason: Any, properties: Any) -> None:
        if reason.is_failure:
            refusal.append(describe_refusal(reason, settings, password is not None))
            return
        # availability first: its retained word arrives before the SUBACK of the replies' topic
        client.subscribe(topics.availability, qos=1)
        subscriptions[client.subscribe(reply_topic, qos=1)[1] or 0] = reply_topic

    def on_subscribe(client: mqtt.Client, userdata: Any, mid: int, *_: Any) -> None:
        if subscriptions.get(mid) == reply_topic:
            subscribed.set()

    def on_connect_fail(client: mqtt.Client, userdata: Any) -> None:
        failed.append(diagnose(settings, ssl_context))

    def on_message(client: mqtt.Client, userdata: Any, message: mqtt.MQTTMessage) -> None:
        if message.topic == topics.availability:
            if message.payload == b"offline":
                offline.append(True)
                answered.set()
            return
        try:
            reply = CommandReply.model_validate_json(message.payload)
        except ValidationError:
            return  # not a reply we can read: keep waiting for ours
        if reply.request_id == request_id:
            found.append(reply)
            answered.set()

    client.on_connect = on_connect
    client.on_connect_fail = on_connect_fail
    client.on_subscribe = on_subscribe
    client.on_message = on_message
    connect_in_background(client, settings)
    try:
        deadline = time.monotonic() + CONNECT_WAIT_S
        while not subscribed.wait(0.05):
            if refusal:
                raise BrokerRefused(refusal[0])
            if failed:  # the first attempt failed: a broker restarting is 'try again later' too
                raise BrokerUnreachable(failed[0])
            if time.monotonic() > deadline:
                raise BrokerUnreachable(f"no connection to the MQTT broker {settings.host}:{settings.port} "
                                        f"within {CONNECT_WAIT_S:g} s")
        if not offline:
            client.publish(topics.command(name), _json.dumps({**payload, "request_id": request_id}), qos=1)
            answered.wait(timeout_s)
    finally:
        client.disconnect()
        client.loop_stop()
    if found:
        return found[0]
    if offline:
        raise Offline(topics.base)
    return None


def run(args: argparse.Namespace) -> int:
    arguments = parse_arguments(args.args)
    settings = settings_of(args)
    # an explicit --command-key-file wins over the environment
    keys = resolve_command_keys(settings, environ={} if args.command_key_file is not None else None)
    base = Topics.from_settings(settings).base
    try:
        reply = send(settings, args.name, arguments, args.timeout, password=resolve_password(), keys=keys,
                     key_id=args.key_id)
    except Offline:
        if args.json:
            print(json.dumps({"ok": None, "command": args.name, "error": "offline", "base": base}))
        print(f"edgedsm cmd: {base} is offline (its retained availability): the daemon is not running",
              file=sys.stderr)
        return EXIT_NO_REPLY
    if reply is None:
        if args.json:
            print(json.dumps({"ok": None, "command": args.name, "error": "no reply", "base": base}))
        print(f"edgedsm cmd: no reply from {base} within {args.timeout:g} s "
              "(is the daemon running, is the device name right?)", file=sys.stderr)
        return EXIT_NO_REPLY
    if args.json:
        print(json.dumps(reply.model_dump(mode="json")))
    elif reply.ok:
        result = f": {json.dumps(reply.result)}" if reply.result else ""
        print(f"{base}: {args.name} accepted{result}")
    if not reply.ok:
        print(f"edgedsm cmd: {base} refused {args.name}: {reply.error}", file=sys.stderr)
        return EXIT_REFUSED
    return 0
