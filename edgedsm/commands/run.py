"""Run the measurement daemon for one camera (what the systemd service starts).

Reads the configuration and checks it on this machine as ``check-config`` does
(``edgedsm.daemon.preflight``; refused with every key path and exit 78 when bad), switches the
laser off, takes dark frames, then measures: S1/S2/S3 maps, per-region statistics and drying
states, published over MQTT. SIGTERM stops (laser off, 'offline' published, exit 0); SIGHUP
reloads the configuration (a bad one is refused and the old one kept).

Example:
  edgedsm run -c /etc/edgedsm/line3.toml
"""

from __future__ import annotations

import argparse
import contextlib
import faulthandler
import logging
import sys
import threading

NAME = "run"
HELP = "run the measurement daemon (systemd service)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-c", "--config", required=True, metavar="CONFIG", help="daemon configuration (TOML)")


def configure_logging(level: str, json_lines: bool) -> None:
    """See :func:`edgedsm.logs.configure_logging`."""
    from edgedsm.logs import configure_logging as configure

    configure(level, json_lines)


def run(args: argparse.Namespace) -> int:
    from edgedsm.config import load_config
    from edgedsm.daemon.preflight import preflight_start
    from edgedsm.daemon.service import Service

    config = load_config(args.config)
    configure_logging(config.logging.level, config.logging.json_lines)
    preflight_start(config)  # check-config's rules, before any sink, camera or relay is opened
    service = Service(args.config, config=config)
    with service.handling_signals():
        code = service.run()
    _name_threads_holding_exit()
    return code


def _name_threads_holding_exit() -> None:
    """The interpreter joins every non-daemon thread before the process ends: one still running
    would hold a stopped daemon past SIGTERM's 2 s, so it is named and its stack written out."""
    holding = [thread for thread in threading.enumerate()
               if thread.is_alive() and not thread.daemon and thread is not threading.main_thread()]
    if holding:
        logging.getLogger(__name__).error("stopped, but threads still running hold the exit: %s (stacks on stderr)",
                                          ", ".join(thread.name for thread in holding))
        with contextlib.suppress(ValueError, OSError, AttributeError):  # a stderr with no file descriptor
            faulthandler.dump_traceback(sys.stderr, all_threads=True)
