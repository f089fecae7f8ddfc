"""Switch the laser relay or ask its state: a field tool to check wiring before the service.

  edgedsm laser status RELAY_URI          read the relay (changes nothing)
  edgedsm laser off RELAY_URI             switch the laser off
  edgedsm laser on RELAY_URI              switch it on and HOLD it on until Ctrl-C, SIGTERM
                                          or SIGHUP, then switch it off again
  edgedsm laser on RELAY_URI --for 10     hold it on for 10 s, then off
  edgedsm laser on RELAY_URI --leave-on   switch it on and exit, leaving it on (careful)

A laser is never left on unattended unless --leave-on says so. Boards with readback
(Numato, KMTronic, Modbus) confirm every switching; LCUS boards cannot, so check those by eye.
Stop the edgedsm service first: the port is opened exclusively.

RELAY_URI (see edgedsm/devices/uri.py for every option):
  serial:/dev/ttyUSB0?protocol=lcus&channel=1
  serial:/dev/ttyACM0?protocol=numato&channel=0
  serial:/dev/ttyUSB0?protocol=kmtronic&channel=1&relays=8
  serial:/dev/ttyUSB0?protocol=modbus&slave=1&channel=0&baud=9600
  serial:socket://10.0.0.7:4001?protocol=modbus     (serial-over-TCP converter)
  sim:                                              (simulated relay, for a dry run)

Exit status: 0 done, 1 the board misbehaved (no answer, bad answer, did not switch),
78 bad RELAY_URI.
"""

from __future__ import annotations

import argparse
import signal
import threading
import time

from edgedsm.devices.laser import LaserRelay, LaserSafety, SignalExit, open_relay
from edgedsm.errors import ConfigError, DeviceError

NAME = "laser"
HELP = "switch the laser relay on/off or read its state (wiring check)"

HOLD_SLICE_S = 3600.0  # sleeping in slices keeps "hold until interrupted" a plain loop


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not 0 <= value <= 86_400:
        raise argparse.ArgumentTypeError("give 0 to 86400 seconds")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("action", choices=("on", "off", "status"),
                        help="on: switch on and hold; off: switch off; status: read the relay")
    parser.add_argument("relay", metavar="RELAY_URI",
                        help="the relay, e.g. serial:/dev/ttyUSB0?protocol=lcus&channel=1")
    hold = parser.add_mutually_exclusive_group()
    hold.add_argument("--for", dest="hold", type=_seconds, metavar="SECONDS",
                      help="with 'on': hold the laser on this long, then switch off "
                           "(default: until Ctrl-C)")
    hold.add_argument("--leave-on", action="store_true",
                      help="with 'on': exit and leave the laser ON (nothing will switch it off)")


def _say(text: str) -> None:
    print(f"laser: {text}", flush=True)


def run(args: argparse.Namespace) -> int:
    if args.action != "on" and (args.hold is not None or args.leave_on):
        raise ConfigError("--for and --leave-on go with 'laser on' only")
    relay = open_relay(args.relay)
    if args.action == "status":
        try:
            _say(relay.state().describe())
        finally:
            relay.detach()  # a status query must not change anything
        return 0
    if args.action == "off":
        with relay:  # close() switches off once more: harmless and safe
            _say(relay.off().describe())
        return 0
    if args.leave_on:
        try:
            status = relay.on()
        except BaseException:
            relay.close()
            raise
        relay.detach()
        _say(f"{status.describe()}; left ON as asked (--leave-on). "
             f"Switch it off with: edgedsm laser off '{args.relay}'")
        return 0
    return _hold_on(relay, args.hold)


def _hold_on(relay: LaserRelay, hold: float | None) -> int:
    """Switch on, hold, switch off; Ctrl-C, SIGTERM and SIGHUP end the hold early."""
    signals = (signal.SIGTERM, signal.SIGHUP)
    in_main = threading.current_thread() is threading.main_thread()
    safety = LaserSafety(relay, signals=signals if in_main else ())
    try:
        with safety as laser:
            _say(laser.on().describe())
            _say(f"holding on for {hold:g} s" if hold is not None
                 else "holding on; press Ctrl-C to switch off")
            deadline = None if hold is None else time.monotonic() + hold
            while deadline is None or time.monotonic() < deadline:
                remaining = HOLD_SLICE_S if deadline is None else deadline - time.monotonic()
                time.sleep(max(0.0, min(HOLD_SLICE_S, remaining)))
            _say(laser.off().describe())
    except (KeyboardInterrupt, SignalExit) as stop:
        why = "Ctrl-C" if isinstance(stop, KeyboardInterrupt) else str(stop)
        if safety.off_error is not None:
            raise DeviceError(f"stopped by {why} but the laser could NOT be switched off: "
                              f"{safety.off_error}") from stop
        _say(f"off ({why}; switched off on the way out)")
    return 0
