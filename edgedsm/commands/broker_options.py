"""Command-line options shared by the commands that talk to a broker (watch, cmd, dashboard):
argument types, the credential/TLS options, and MQTT settings from a daemon config plus options.

The password never comes from the command line: ``$EDGEDSM_MQTT_PASSWORD`` or
``$CREDENTIALS_DIRECTORY/mqtt-password`` (``edgedsm.publish.settings.resolve_password``).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from edgedsm.errors import ConfigError
from edgedsm.publish.settings import CADENCE_KEYS, MqttSettings
from edgedsm.validation import read_toml, validate


def host_port(default_port: int | None = None) -> Callable[[str], tuple[str, int]]:
    """argparse type for ``HOST:PORT`` (``HOST`` alone when a default port is given)."""

    def parse(text: str) -> tuple[str, int]:
        host, colon, port = text.rpartition(":")
        if not colon and default_port is not None:
            host, port = text, str(default_port)
        if not host or not port.isdigit() or not 0 <= int(port) <= 65535:
            raise argparse.ArgumentTypeError(f"{text!r} is not HOST:PORT (port 0..65535)")
        return host.strip("[]"), int(port)

    return parse


def seconds(text: str) -> float:
    """argparse type for a duration in seconds, above 0 and at most an hour."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0 < value <= 3600:
        raise argparse.ArgumentTypeError("give a number above 0 and at most 3600")
    return value


def add_credential_options(group: argparse._ActionsContainer) -> None:
    """``--username``, ``--tls``, ``--ca-file``, ``--cert-file``, ``--key-file``, ``--insecure``."""
    group.add_argument("--username", help="user name; the password is read from $EDGEDSM_MQTT_PASSWORD")
    group.add_argument("--tls", action="store_true", help="use TLS (implied by --ca-file/--cert-file)")
    group.add_argument("--ca-file", type=Path, help="CA certificate(s) of the broker (PEM)")
    group.add_argument("--cert-file", type=Path, help="client certificate (PEM)")
    group.add_argument("--key-file", type=Path, help="client key (PEM)")
    group.add_argument("--insecure", action="store_true",
                       help="do not check that the broker's certificate names the host")


def mqtt_settings(config: Path | None, args: argparse.Namespace, overrides: Mapping[str, Any], *,
                  require_table: bool = True, with_device: bool = True) -> MqttSettings:
    """Broker settings: a daemon config's ``[mqtt]`` table (and its ``[device] name``), then the
    options in ``overrides`` (None values ignored) and the credential/TLS options of ``args``.

    The daemon's ``client_id`` is never taken (using it would throw the daemon off the broker).
    ``require_table``: a config without ``[mqtt]`` is an error; ``with_device``: keep the device
    name (a plant-wide subscriber such as the dashboard drops it).
    """
    data: dict[str, Any] = {}
    source = "command line"
    if config is not None:
        document = read_toml(config)
        table = document.get("mqtt")
        if isinstance(table, dict):
            data, source = dict(table), f"{config}: mqtt"
            device = document.get("device", {})
            if "device" not in data and isinstance(device, dict) and "name" in device:
                data["device"] = device["name"]  # the daemon names its topics after [device] name
        elif require_table:
            raise ConfigError(f"{config}: has no [mqtt] table")
    data.pop("client_id", None)
    for key in CADENCE_KEYS:  # a daemon's cadence (deprecated there), nothing a subscriber uses
        data.pop(key, None)
    if not with_device:
        data.pop("device", None)
    data.update({key: value for key, value in overrides.items() if value is not None})
    if args.username is not None:
        data["username"] = args.username
    if args.tls or args.ca_file or args.cert_file or args.key_file or args.insecure:
        tls = dict(data.get("tls") or {})
        for key in ("ca_file", "cert_file", "key_file"):
            if getattr(args, key) is not None:
                tls[key] = getattr(args, key)
        if args.insecure:
            tls["insecure"] = True
        data["tls"] = tls
    return validate(MqttSettings, data, source)
