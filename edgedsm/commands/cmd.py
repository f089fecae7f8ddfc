"""Send one command to a running daemon over MQTT and wait for its reply (for scripts).

The command goes to ``<prefix>/<device>/cmd/NAME`` with a fresh ``request_id``; the reply with
that id on ``<prefix>/<device>/cmd/NAME/reply`` decides the exit status:

  0  the daemon accepted and carried out the command
  1  the daemon refused it (the reason is printed)
  2  no reply within --timeout (daemon not running, wrong --device, broker dropped it)

Commands (docs/mqtt.md): laser {"state": "on"|"off"|"auto"}, rebaseline, dark, publish_maps,
record {"seconds": S} (a clip, with [recording]).

Examples:
  edgedsm cmd publish_maps -c /etc/edgedsm/line3.toml
  edgedsm cmd laser --device line3 --broker broker.local:1883 --args '{"state": "off"}'
  edgedsm cmd rebaseline --device line3 --json      # the reply as JSON on stdout
  edgedsm cmd record -c /etc/edgedsm/line3.toml --args '{"seconds": 30}'

Connection settings come from the config's [mqtt] table (-c) and/or the options; options win.
The password comes from $EDGEDSM_MQTT_PASSWORD (or $CREDENTIALS_DIRECTORY/mqtt-password).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import threading
import time
import uuid
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
from pydantic import ValidationError

from edgedsm import _json
from edgedsm.commands.broker_options import add_credential_options, host_port, mqtt_settings, seconds
from edgedsm.errors import DataError
from edgedsm.publish.commands import CommandReply
from edgedsm.publish.connection import build_ssl_context, connect_in_background, describe_refusal, make_client
from edgedsm.publish.errors import PublishError
from edgedsm.publish.settings import MqttSettings, resolve_password
from edgedsm.publish.topics import Topics

NAME = "cmd"
HELP = "send a command to a running daemon and wait for its reply (exit 0 accepted, 1 refused, 2 no reply)"

EXIT_REFUSED = 1
EXIT_NO_REPLY = 2
CONNECT_WAIT_S = 10.0


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
    add_credential_options(parser.add_argument_group("credentials and TLS (as the daemon's [mqtt])"))


def settings_of(args: argparse.Namespace) -> MqttSettings:
    """Broker settings as ``edgedsm watch`` builds them (config, then options)."""
    host, port = args.broker if args.broker is not None else (None, None)
    return mqtt_settings(args.config, args, {"host": host, "port": port, "topic_prefix": args.topic_prefix,
                                             "device": args.device})


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


def send(settings: MqttSettings, name: str, arguments: dict[str, Any], timeout_s: float,
         password: str | None = None) -> CommandReply | None:
    """Publish the command and wait for the reply carrying its request id (None: no reply in time)."""
    topics = Topics.from_settings(settings)
    request_id = f"cli-{uuid.uuid4().hex[:12]}"
    reply_topic = topics.reply(name)
    subscribed, answered = threading.Event(), threading.Event()
    found: list[CommandReply] = []
    refusal: list[str] = []
    client = make_client(settings, client_id=f"edgedsm-cmd-{os.getpid()}-{uuid.uuid4().hex[:6]}",
                         password=password, ssl_context=build_ssl_context(settings.tls) if settings.tls else None,
                         protocol="3.1.1")

    def on_connect(client: mqtt.Client, userdata: Any, flags: Any, reason: Any, properties: Any) -> None:
        if reason.is_failure:
            refusal.append(describe_refusal(reason, settings, password is not None))
            return
        client.subscribe(reply_topic, qos=1)

    def on_message(client: mqtt.Client, userdata: Any, message: mqtt.MQTTMessage) -> None:
        try:
            reply = CommandReply.model_validate_json(message.payload)
        except ValidationError:
            return  # not a reply we can read: keep waiting for ours
        if reply.request_id == request_id:
            found.append(reply)
            answered.set()

    client.on_connect = on_connect
    client.on_subscribe = lambda *_: subscribed.set()
    client.on_message = on_message
    connect_in_background(client, settings)
    try:
        deadline = time.monotonic() + CONNECT_WAIT_S
        while not subscribed.wait(0.05):
            if refusal:
                raise PublishError(refusal[0])
            if time.monotonic() > deadline:
                raise PublishError(f"no connection to the MQTT broker {settings.host}:{settings.port} "
                                   f"within {CONNECT_WAIT_S:g} s")
        client.publish(topics.command(name), _json.dumps({**arguments, "request_id": request_id}), qos=1)
        answered.wait(timeout_s)
    finally:
        client.disconnect()
        client.loop_stop()
    return found[0] if found else None


def run(args: argparse.Namespace) -> int:
    arguments = parse_arguments(args.args)
    settings = settings_of(args)
    reply = send(settings, args.name, arguments, args.timeout, password=resolve_password())
    base = Topics.from_settings(settings).base
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
