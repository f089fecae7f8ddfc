"""The operator's live plant dashboard: one web page for every edgedsm daemon of a plant.

Subscribes to <prefix>/+/# on the broker and serves, on --listen, a page with every device seen
(availability, drying states, activity, time to dry, maps with the regions drawn, activity
curves, alerts, fps, drops, ambient level, laser state), pushed live. History (per-region
activity, states, alerts) is kept in SQLite (--database) for --retention-days.

Commands (rebaseline, dark, publish_maps) are sent only with a token: set $EDGEDSM_DASHBOARD_TOKEN
(or the systemd credential dashboard-token); without one the page is read-only. The dashboard
never switches the laser.

Who may view: by default anyone who reaches --listen (127.0.0.1:8080: this machine only). For a
plant network set a viewer password ($EDGEDSM_DASHBOARD_VIEWER_PASSWORD or the systemd credential
dashboard-viewer-password) and HTTPS (--tls-cert/--tls-key, or a TLS reverse proxy). Requests whose
Host header is not an IP address, localhost, this machine's name or an --allowed-host are refused
(421: DNS rebinding). Connections are capped and timed (--max-connections ...; docs/dashboard.md).

Examples:
  edgedsm dashboard --broker broker.local:1883                      # http://127.0.0.1:8080/
  edgedsm dashboard --listen 0.0.0.0:8443 --tls-cert dash.crt --tls-key dash.key --allowed-host dash.plant.local
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
VIEWER_ENV = "EDGEDSM_DASHBOARD_VIEWER_PASSWORD"
VIEWER_CREDENTIAL = "dashboard-viewer-password"


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
    web = parser.add_argument_group("who may view the page (docs/dashboard.md, Security)")
    web.add_argument("--allowed-host", dest="allowed_hosts", action="append", default=[], metavar="NAME",
                     help="a host name the page may be reached by, beside IP addresses, localhost and this "
                          "machine's names (repeatable; other Host headers get 421)")
    web.add_argument("--tls-cert", type=Path, metavar="PEM", help="serve HTTPS with this certificate (chain)")
    web.add_argument("--tls-key", type=Path, metavar="PEM", help="the certificate's private key")
    web.add_argument("--max-connections", type=int, metavar="N",
                     help=f"connections open at once (default {_limit('max_connections')})")
    web.add_argument("--max-per-client", type=int, metavar="N",
                     help=f"connections open at once from one address (default {_limit('max_per_client')}; "
                          "behind a reverse proxy every viewer is the proxy)")
    web.add_argument("--max-event-streams", type=int, metavar="N",
                     help=f"open pages (live event streams) at once (default {_limit('max_event_streams')})")
    web.add_argument("--max-event-streams-per-client", type=int, metavar="N",
                     help=f"open pages from one address (default {_limit('max_event_streams_per_client')}; "
                          "behind a reverse proxy every viewer is the proxy)")
    web.add_argument("--header-timeout", type=float, metavar="S",
                     help=f"a new connection's request headers must arrive within S seconds "
                          f"(default {_limit('header_timeout_s')})")
    web.add_argument("--idle-timeout", type=float, metavar="S",
                     help=f"an idle keep-alive connection is closed after S seconds "
                          f"(default {_limit('idle_timeout_s')})")
    tls = parser.add_argument_group("credentials and TLS (as the daemon's [mqtt])")
    add_credential_options(tls)


def _limit(name: str) -> object:
    from edgedsm.publish.http_guard import ConnectionLimits

    return ConnectionLimits.model_fields[name].default


def access_settings(args: argparse.Namespace):  # -> AccessSettings (import kept local: the CLI starts fast)
    """The web-facing settings from the options; a bad value is a config error naming the option."""
    from pydantic import ValidationError

    from edgedsm.dashboard.access import AccessSettings
    from edgedsm.publish.http_guard import ConnectionLimits

    given = {"max_connections": args.max_connections, "max_per_client": args.max_per_client,
             "max_event_streams": args.max_event_streams,
             "max_event_streams_per_client": args.max_event_streams_per_client,
             "header_timeout_s": args.header_timeout, "idle_timeout_s": args.idle_timeout}
    limits = {key: value for key, value in given.items() if value is not None}
    if "max_event_streams" in limits and "max_event_streams_per_client" not in limits:
        limits["max_event_streams_per_client"] = min(limits["max_event_streams"],
                                                     ConnectionLimits.model_fields["max_event_streams_per_client"].default)
    options = {"max_connections": "--max-connections", "max_per_client": "--max-per-client",
               "max_event_streams": "--max-event-streams",
               "max_event_streams_per_client": "--max-event-streams-per-client", "header_timeout_s": "--header-timeout",
               "idle_timeout_s": "--idle-timeout", "allowed_hosts": "--allowed-host", "tls_cert": "--tls-cert",
               "tls_key": "--tls-key"}
    try:
        return AccessSettings(allowed_hosts=args.allowed_hosts, tls_cert=args.tls_cert, tls_key=args.tls_key,
                              limits=ConnectionLimits(**limits))
    except ValidationError as exc:
        error = exc.errors()[0]
        where = ", ".join(options.get(str(part), str(part)) for part in error["loc"]) or "dashboard options"
        raise ConfigError(f"{where}: {error['msg']}") from None


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


def _secret(env_name: str, credential: str, environ: dict[str, str] | None) -> str:
    env = os.environ if environ is None else environ
    value = env.get(env_name, "").strip()
    if not value and env.get("CREDENTIALS_DIRECTORY"):
        path = Path(env["CREDENTIALS_DIRECTORY"]) / credential
        value = path.read_text(encoding="utf-8").strip() if path.is_file() else ""
    return value


def resolve_token(environ: dict[str, str] | None = None) -> str | None:
    """The command token from $EDGEDSM_DASHBOARD_TOKEN or $CREDENTIALS_DIRECTORY/dashboard-token."""
    token = _secret(TOKEN_ENV, TOKEN_CREDENTIAL, environ)
    if token and len(token) < 16:
        raise ConfigError(f"{TOKEN_ENV}: the command token must have at least 16 characters")
    return token or None


def resolve_viewer_password(environ: dict[str, str] | None = None) -> str | None:
    """The viewer password from $EDGEDSM_DASHBOARD_VIEWER_PASSWORD or the credential
    dashboard-viewer-password; None: viewing needs no login."""
    from edgedsm.dashboard.access import MIN_PASSWORD

    password = _secret(VIEWER_ENV, VIEWER_CREDENTIAL, environ)
    if password and len(password) < MIN_PASSWORD:
        raise ConfigError(f"{VIEWER_ENV}: the viewer password must have at least {MIN_PASSWORD} characters")
    return password or None


def run(args: argparse.Namespace) -> int:
    from edgedsm.dashboard.app import Dashboard, DashboardSettings

    if not 0 < args.retention_days <= 3650:
        raise ConfigError("--retention-days: must be in (0, 3650]")
    settings = DashboardSettings(mqtt=broker_settings(args), listen=args.listen, database=args.database,
                                 retention_s=args.retention_days * 86400.0, token=resolve_token(),
                                 daemon_configs=config_files(args), access=access_settings(args),
                                 viewer_password=resolve_viewer_password())
    try:
        dashboard = Dashboard(settings, password=resolve_password())
    except OSError as exc:
        raise ConfigError(f"--listen {args.listen[0]}:{args.listen[1]}: {exc.strerror or exc}") from None
    dashboard.start()
    print(f"edgedsm dashboard: {dashboard.url} (broker {settings.mqtt.host}:{settings.mqtt.port}, "
          f"{dashboard.subscriber.subscription}; {'commands with token' if settings.token else 'read-only'}"
          f"{'; viewer login' if settings.viewer_password else ''})",
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
