"""Watch a running edgedsm daemon over MQTT: availability, drying-state changes and alerts, live.

Prints one line per event, with the time it arrived:

  2025-06-01 12:00:01.123  availability  online
  2025-06-01 12:00:01.125  state         panel: wet (activity 0.412)
  2025-06-01 12:04:09.871  state         panel: wet -> drying (activity 0.287)
  2025-06-01 12:04:09.872  alert #12     panel: wet -> drying (activity 0.287) [transition]

Payloads are parsed as the daemon's typed messages (edgedsm.messages); one that does not parse
is printed as "unreadable" with the reason. Alerts are delivered at least once; watch prints
each one once (it deduplicates on the alert's stream and seq). With --client-id it keeps a
persistent session on the broker, so alerts raised while it was not running are delivered when
it comes back (as long as the broker keeps sessions). Exit after N alerts with --count, after S seconds with --timeout
(for scripts and tests): exit status 0, or 1 if --count was not reached in time.

Examples:
  edgedsm watch --host broker.local --device line3
  edgedsm watch -c /etc/edgedsm/line3.toml --save-maps /tmp/maps
  edgedsm watch --device line3 --count 1 --timeout 600     # wait for the next alert
  EDGEDSM_MQTT_PASSWORD=... edgedsm watch --host broker --port 8883 --ca-file ca.pem --username op

Connection settings come from the [mqtt] table of a daemon config (-c) and/or the options;
options win. The password comes from $EDGEDSM_MQTT_PASSWORD (or
$CREDENTIALS_DIRECTORY/mqtt-password), never from the command line.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from edgedsm.commands.broker_options import add_credential_options, mqtt_settings
from edgedsm.commands.watcher import CONNECT_WAIT_S, Watcher
from edgedsm.publish.settings import MqttSettings, resolve_password

NAME = "watch"
HELP = "print a daemon's availability, state changes and alerts live (MQTT subscriber)"

#: After this long connected without any availability on our base, say so (retained: it is
#: there at once when a daemon ever ran under this name).
SILENCE_HINT_S = 2.0


def _positive(kind: type, low: float) -> Callable[[str], Any]:
    def parse(text: str) -> Any:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if value < low:
            raise argparse.ArgumentTypeError(f"must be at least {low}")
        return value
    return parse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-c", "--config", type=Path, metavar="CONFIG",
                        help="take the broker settings from this daemon config's [mqtt] table")
    conn = parser.add_argument_group("connection (override the config)")
    conn.add_argument("--host", help="broker host (default localhost)")
    conn.add_argument("--port", type=int, help="broker port (default 1883)")
    conn.add_argument("--prefix", dest="topic_prefix", metavar="PREFIX", help="topic prefix (default edgedsm)")
    conn.add_argument("--device", help="device in the topics (default: the config's, else camera1 as the daemon)")
    add_credential_options(conn)
    conn.add_argument("--client-id", help="fixed client id: a persistent session, so alerts raised while "
                                          "watch is away are delivered when it returns")
    out = parser.add_argument_group("output")
    out.add_argument("--save-maps", type=Path, metavar="DIR",
                     help="decode received maps and save them as colour-mapped PNG files in DIR")
    out.add_argument("--stats", action="store_true", help="also print every statistics message")
    stop = parser.add_argument_group("stopping")
    stop.add_argument("--count", type=_positive(int, 1), metavar="N", help="exit after N distinct alerts")
    stop.add_argument("--timeout", type=_positive(float, 0.0), metavar="S", help="exit after S seconds")
    out.add_argument("--json", action="store_true", help="one JSON object per event (for scripts)")


def settings_from_args(args: argparse.Namespace) -> MqttSettings:
    """Broker settings: the config's [mqtt] table (if any) overridden by the options."""
    return mqtt_settings(args.config, args, {"host": args.host, "port": args.port, "topic_prefix": args.topic_prefix,
                                             "device": args.device})


def run(args: argparse.Namespace) -> int:
    settings = settings_from_args(args)
    if args.save_maps is not None:
        args.save_maps.mkdir(parents=True, exist_ok=True)
    watcher = Watcher(settings, password=resolve_password(), client_id=args.client_id,
                      save_maps=args.save_maps, show_stats=args.stats, count=args.count, json_lines=args.json)
    if args.config is None and args.device is None:
        # the daemon's default name: say so, a daemon named otherwise would look silent
        print(f"edgedsm watch: watching {watcher.topics.base} (default device name; give --device or -c CONFIG "
              "for another)", file=sys.stderr)
    deadline = None if args.timeout is None else time.monotonic() + args.timeout
    watcher.start(wait_s=CONNECT_WAIT_S if deadline is None else max(0.5, min(CONNECT_WAIT_S, args.timeout)))
    timed_out = False
    silent_check = time.monotonic() + SILENCE_HINT_S
    try:
        while not watcher.done.is_set():
            if time.monotonic() >= silent_check:
                watcher.hint_if_silent()
            remaining = None if deadline is None else deadline - time.monotonic()
            if remaining is not None and remaining <= 0:
                timed_out = True
                break
            watcher.done.wait(0.5 if remaining is None else min(0.5, remaining))
    except KeyboardInterrupt:
        pass  # Ctrl-C is the normal way to stop watching
    finally:
        watcher.done.set()
        watcher.stop()
    if timed_out and args.count is not None and len(watcher.alerts_seen) < args.count:
        print(f"edgedsm watch: timed out after {args.timeout:g} s with {len(watcher.alerts_seen)} of "
              f"{args.count} alert(s)", file=sys.stderr)
        return 1
    return 0
