"""The operator's live plant dashboard: one web page for every edgedsm daemon of a plant.

Subscribes to <prefix>/+/# on the broker and serves, on --listen, a page with every device seen
(availability, drying states, activity, time to dry, maps with the regions drawn, activity
curves, alerts, fps, drops, ambient level, laser state), pushed live. History (per-region
activity, states, alerts) is kept in SQLite (--database) for --retention-days.

Commands (rebaseline, dark, publish_maps) are sent only with a token: set $EDGEDSM_DASHBOARD_TOKEN
(or the systemd credential dashboard-token); without one the page is read-only. The dashboard
never switches the laser.

Examples:
  edgedsm dashboard --broker broker.local:1883 --listen 0.0.0.0:8080
  edgedsm dashboard -c /etc/edgedsm/line3.toml -c /etc/edgedsm/line4.toml   # broker + region outlines
  EDGEDSM_MQTT_PASSWORD=... edgedsm dashboard --broker broker:8883 --ca-file ca.pem --username dash

Connection settings come from the [mqtt] table of the first daemon config (-c) and/or the
options; options win. Each -c config also gives its device's region outlines and thresholds.
"""

from __future__ import annotations

import argparse
import os
import signal
import threading
from pathlib import Path

from edgedsm.commands import broker_options
from edgedsm.commands.broker_options import add_credential_options, host_port
from edgedsm.errors import ConfigError
from edgedsm.publish.settings import MqttSettings, resolve_password
from edgedsm.signals import handling, wait_for

NAME = "dashboard"
HELP = "serve the live plant dashboard (maps, regions, drying curves, alerts) for every daemon on a broker"
TOKEN_ENV = "EDGEDSM_DASHBOARD_TOKEN"
TOKEN_CREDENTIAL = "dashboard-token"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-c", "--config", type=Path, action="append", default=[], metavar="CONFIG",
                        help="a daemon config: the first gives the [mqtt] settings; each gives its device's "
                             "region outlines and thresholds (repeatable)")
    parser.add_argument("--config-dir", type=Path, metavar="DIR",
                        help="every *.toml in DIR as a -c config (after those given with -c), e.g. /etc/edgedsm")
    parser.add_argument("--broker", type=host_port(1883), metavar="HOST:PORT",
                        help="the broker (default localhost:1883)")
    parser.add_argument("--prefix", dest="topic_prefix", metavar="PREFIX", help="topic prefix (default edgedsm)")
    parser.add_argument("--listen", type=host_port(8080), default=("127.0.0.1", 8080),
                        metavar="HOST:PORT", help="where the page is served (default 127.0.0.1:8080)")
    parser.add_argument("--database", type=Path, metavar="FILE",
                        default=Path(os.environ.get("STATE_DIRECTORY", ".")) / "dashboard.sqlite3",
                        help="SQLite history (default $STATE_DIRECTORY/dashboard.sqlite3 or ./dashboard.sqlite3)")
    parser.add_argument("--retention-days", type=float, default=7.0, metavar="DAYS",
                        help="history kept (default 7 days)")
    tls = parser.add_argument_group("credentials and TLS (as the daemon's [mqtt])")
    add_credential_options(tls)


def config_files(args: argparse.Namespace) -> list[Path]:
    """The -c configs, then those of --config-dir (sorted by name)."""
    files = list(args.config)
    if args.config_dir is not None:
        if not args.config_dir.is_dir():
            raise ConfigError(f"--config-dir: {args.config_dir}: not a directory")
        files += sorted(path for path in args.config_dir.glob("*.toml") if path not in files)
    return files


def broker_settings(args: argparse.Namespace) -> MqttSettings:
    """The first config's [mqtt] table (without its device: the dashboard watches them all), then the options."""
    configs = config_files(args)
    host, port = args.broker if args.broker is not None else (None, None)
    return broker_options.mqtt_settings(configs[0] if configs else None, args,
                                        {"host": host, "port": port, "topic_prefix": args.topic_prefix},
                                        require_table=False, with_device=False)


def resolve_token(environ: dict[str, str] | None = None) -> str | None:
    """The command token from $EDGEDSM_DASHBOARD_TOKEN or $CREDENTIALS_DIRECTORY/dashboard-token."""
    env = os.environ if environ is None else environ
    token = env.get(TOKEN_ENV, "").strip()
    if not token and env.get("CREDENTIALS_DIRECTORY"):
        path = Path(env["CREDENTIALS_DIRECTORY"]) / TOKEN_CREDENTIAL
        token = path.read_text(encoding="utf-8").strip() if path.is_file() else ""
    if token and len(token) < 16:
        raise ConfigError(f"{TOKEN_ENV}: the command token must have at least 16 characters")
    return token or None


def run(args: argparse.Namespace) -> int:
    from edgedsm.dashboard.app import Dashboard, DashboardSettings

    if not 0 < args.retention_days <= 3650:
        raise ConfigError("--retention-days: must be in (0, 3650]")
    settings = DashboardSettings(mqtt=broker_settings(args), listen=args.listen, database=args.database,
                                 retention_s=args.retention_days * 86400.0, token=resolve_token(),
                                 daemon_configs=config_files(args))
    try:
        dashboard = Dashboard(settings, password=resolve_password())
    except OSError as exc:
        raise ConfigError(f"--listen {args.listen[0]}:{args.listen[1]}: {exc.strerror or exc}") from None
    dashboard.start()
    print(f"edgedsm dashboard: {dashboard.url} (broker {settings.mqtt.host}:{settings.mqtt.port}, "
          f"{dashboard.subscriber.subscription}; {'commands with token' if settings.token else 'read-only'})",
          flush=True)
    stop = threading.Event()
    with handling({signal.SIGTERM: lambda *_: stop.set(), signal.SIGINT: lambda *_: stop.set()}):
        thread = threading.Thread(target=dashboard.serve_forever, name="dashboard-http", daemon=True)
        thread.start()
        try:
            wait_for(stop)  # in slices: a signal taken by another thread still sets it
        finally:
            dashboard.stop()
    return 0
