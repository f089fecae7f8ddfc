"""Switch the laser relay or ask its state: a field tool, and the service's last line of defence.

  edgedsm laser status RELAY_URI          read the relay (changes nothing)
  edgedsm laser off RELAY_URI             switch the laser off
  edgedsm laser off --config FILE         switch off the relay a daemon config names ([laser] uri);
                                          what the unit's ExecStopPost= runs after ANY end of the
                                          service (kill -9, OOM, crash), without the daemon
  edgedsm laser on RELAY_URI              switch it on and HOLD it on until Ctrl-C, SIGTERM
                                          or SIGHUP, then switch it off again
  edgedsm laser on RELAY_URI --for 10     hold it on for 10 s, then off
  edgedsm laser on RELAY_URI --leave-on   switch it on and exit, leaving it on (careful)

A laser is never left on unattended unless --leave-on says so. Boards with readback
(Numato, KMTronic, Modbus) confirm every switching; LCUS boards cannot, so check those by eye.
Stop the edgedsm service first: the port is opened exclusively, and 'on' and 'status' refuse
a port another process holds (exit 69). 'off' does not: off is always safe to send, so when a
process holds the port's lock (a daemon hung or stopped with the laser on) it opens the port
without the lock, switches off and reads back as always, and says whose lock it overrode
(docs/laser-safety.md, "Off overrides the port lock").

With --config, a config whose other tables do not validate still has its [laser] uri used to
switch off (safety first); the configuration error is reported and the exit status is 78.
A config without [laser] has nothing to switch: exit 0 with a message.

RELAY_URI (see edgedsm/devices/uri.py for every option):
  serial:/dev/ttyUSB0?protocol=lcus&channel=1
  serial:/dev/ttyACM0?protocol=numato&channel=0
  serial:/dev/ttyUSB0?protocol=kmtronic&channel=1&relays=8
  serial:/dev/ttyUSB0?protocol=modbus&slave=1&channel=0&baud=9600
  serial:socket://10.0.0.7:4001?protocol=modbus     (serial-over-TCP converter)
  sim:                                              (simulated relay, for a dry run)

Exit status: 0 done (off: confirmed by readback where the board has it), 69 the relay is
unreachable or misbehaved (no answer, bad answer, did not switch, port missing; for on and
status also a port another process holds), 78 bad RELAY_URI or configuration.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from pathlib import Path

from edgedsm.devices.laser import LaserRelay, LaserSafety, PortLocked, RelayStatus, SignalExit, open_relay
from edgedsm.errors import ConfigError, DeviceError
from edgedsm.signals import SIGNAL_SLICE_S

NAME = "laser"
HELP = "switch the laser relay on/off or read its state; 'off --config FILE' after the service"

#: The hold sleeps in slices this long (s): a signal taken by another thread runs its handler when
#: the main thread's sleep ends (edgedsm.signals), so the slice bounds how late the laser goes off.
HOLD_SLICE_S = SIGNAL_SLICE_S
EXIT_UNAVAILABLE = 69  # EX_UNAVAILABLE: the relay cannot be reached or did not do as told
OFF_ATTEMPTS = 3       # --config: a board busy for a moment gets a second and third chance
OFF_RETRY_S = 0.5


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
    parser.add_argument("relay", metavar="RELAY_URI", nargs="?",
                        help="the relay, e.g. serial:/dev/ttyUSB0?protocol=lcus&channel=1")
    parser.add_argument("-c", "--config", type=Path, metavar="FILE",
                        help="take the relay from this daemon config's [laser] uri instead")
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
    if (args.relay is None) == (args.config is None):
        raise ConfigError("name the relay: give either RELAY_URI or --config FILE (not both)")
    try:
        if args.config is not None:
            return _run_from_config(args)
        return _run(args, args.relay)
    except DeviceError as exc:
        # the same one-line form as the other errors; 69 tells systemd and scripts "device"
        print(f"edgedsm: error: {exc}", file=sys.stderr)
        return EXIT_UNAVAILABLE


def _run(args: argparse.Namespace, uri: str) -> int:
    relay = _open_for_off(uri) if args.action == "off" else open_relay(uri)
    if args.action == "status":
        try:
            _say(relay.state().describe())
        finally:
            relay.detach()  # a status query must not change anything
        return 0
    if args.action == "off":
        with relay:  # close() switches off once more: harmless and safe
            _say(_switch_off(relay).describe())
        return 0
    if args.leave_on:
        try:
            status = relay.on()
        except BaseException:
            relay.close()
            raise
        relay.detach()
        _say(f"{status.describe()}; left ON as asked (--leave-on). "
             f"Switch it off with: edgedsm laser off '{uri}'")
        return 0
    return _hold_on(relay, args.hold)


def _open_for_off(uri: str) -> LaserRelay:
    """The relay, to switch it off: opened with the port's lock as always; when another process
    holds it (a daemon hung or stopped, SIGSTOP, with the laser on), without: off is idempotent
    and always safe, and the readback confirms it whatever that process left in the port's
    buffers. Never used for on."""
    try:
        return open_relay(uri)
    except PortLocked as exc:
        by = f"process {exc.holder}" if exc.holder else "another process"
        print(f"edgedsm: warning: relay port {exc.port} is locked by {by}: overriding the lock to switch "
              "the laser off (off only)", file=sys.stderr, flush=True)
        return open_relay(uri, exclusive=False)


def _switch_off(relay: LaserRelay) -> RelayStatus:
    """Switch off and, where the board can tell, read it back even if the URI says verify=false."""
    status = relay.off()
    if relay.readback and not status.confirmed:
        status = relay.state()
        if status.on:
            raise DeviceError(f"{relay.description}: commanded off but the board reports on "
                              f"(stuck relay or wiring fault?)")
    return status


def _run_from_config(args: argparse.Namespace) -> int:
    """The relay of a daemon config; a config error elsewhere does not stop switching off."""
    from edgedsm.config import load_config
    from edgedsm.validation import read_toml

    config_error: ConfigError | None = None
    try:
        config = load_config(args.config)
        uri = config.laser.uri if config.laser is not None else None
    except ConfigError as exc:
        if args.action != "off":
            raise
        config_error = exc
        laser = read_toml(args.config).get("laser")  # unreadable or not TOML: ConfigError, 78
        uri = laser.get("uri") if isinstance(laser, dict) else None
        if not isinstance(uri, str):
            raise
    if uri is None:
        _say(f"{args.config} has no [laser] table: no relay to switch")
        return 0
    if args.action != "off":
        return _run(args, uri)
    _off_with_retries(uri)
    if config_error is not None:
        print(f"edgedsm: configuration error (the laser was switched off all the same, "
              f"from [laser] uri):\n{config_error}", file=sys.stderr)
        return ConfigError.exit_code
    return 0


def _off_with_retries(uri: str) -> None:
    """Open, switch off, confirm; up to OFF_ATTEMPTS times (a port may be busy for a moment)."""
    for attempt in range(1, OFF_ATTEMPTS + 1):
        try:
            with _open_for_off(uri) as relay:
                _say(_switch_off(relay).describe())
            return
        except DeviceError as exc:
            if attempt == OFF_ATTEMPTS:
                raise DeviceError(f"the laser may still be ON: {OFF_ATTEMPTS} attempts to switch "
                                  f"it off failed; the last: {exc}") from exc
            print(f"edgedsm: attempt {attempt} to switch the laser off failed: {exc}",
                  file=sys.stderr, flush=True)
            time.sleep(OFF_RETRY_S)


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
