"""Run the main job on simulated devices: activity maps, then the daemon watching a plate dry.

Part 1 (maps): simulates the built-in default scene (the paper's logo object: letters "IOMT"
and "ETRI" with τc = 10 Δt on a background with τc = 50 Δt, 200 frames of 256x256, 8-bit
detector), computes S1, S2, S3 with lag 10, writes each as .npy (float64) and as a
colour-mapped PNG, and prints the mean activity per region and the contrast β.

Part 2 (daemon, skip with --no-daemon): runs the measurement daemon on config/daemon/demo.toml
(a simulated plate drying in under a minute, simulated laser relay) against a private mosquitto
started on a free loopback port with the shipped broker configuration (config/mosquitto: TLS,
a password per user, the ACL; docs/security.md) or against --broker HOST:PORT, and prints what
a subscriber sees (edgedsm watch): availability, then the plate going wet -> drying -> dry.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import re
import shutil
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from edgedsm.analysis import contrast, region_mean
from edgedsm.commands.common import add_progress_flag, progress, scene_argument
from edgedsm.config import DaemonConfig
from edgedsm.errors import EdgedsmError
from edgedsm.estimators import ESTIMATORS, all_maps
from edgedsm.imageio import save_map_png
from edgedsm.publish.settings import PASSWORD_ENV, MqttSettings, MqttTlsSettings
from edgedsm.resources import data_file
from edgedsm.signals import wait_for

if TYPE_CHECKING:
    from edgedsm.dashboard.app import Dashboard

NAME = "demo"
HELP = "activity maps of a simulated scene, then the daemon watching a plate dry (the README's first command)"
DEMO_CONFIG = data_file("config/daemon/demo.toml")  # package data, also in an installed wheel


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scene", default="default", help="scene TOML file (default: built-in logo scene)")
    parser.add_argument("-o", "--output", default="edgedsm-demo", help="output directory (default ./edgedsm-demo)")
    parser.add_argument("--lag", type=int, default=10, help="time lag m in frames (default 10)")
    parser.add_argument("--q", type=float, default=0.0, help="S2 regulariser q (default 0)")
    parser.add_argument("--no-daemon", dest="daemon", action="store_false", help="only part 1 (the maps)")
    parser.add_argument("--daemon-config", type=Path, default=DEMO_CONFIG,
                        help="daemon config of part 2 (default: config/daemon/demo.toml)")
    parser.add_argument("--broker", metavar="HOST:PORT", help="use this broker instead of a private mosquitto")
    parser.add_argument("--time-limit", type=float, default=180.0, help="seconds part 2 may take (default 180)")
    parser.add_argument("--dashboard", metavar="HOST:PORT", default="127.0.0.1:8080",
                        help="serve the plant dashboard of part 2 here (default 127.0.0.1:8080, another free "
                             "port if taken; 'off': none); on a terminal it stays up until Ctrl-C")
    add_progress_flag(parser)


def run(args: argparse.Namespace) -> int:
    from edgedsm.sim import Simulator, region_masks  # here: keeps the CLI's start-up light
    scene = scene_argument(args.scene)
    count = scene.scene.frames
    simulator = Simulator(scene)
    start = time.perf_counter()
    stack = np.stack(list(progress(simulator.frames(), count, "simulate", args.progress)))
    simulated = time.perf_counter() - start
    maps = all_maps(stack, args.lag, q=args.q)
    computed = time.perf_counter() - start - simulated

    output = Path(args.output)
    output.mkdir(parents=True, exist_ok=True)
    np.save(output / "frames.npy", stack)
    for name in ESTIMATORS:
        np.save(output / f"{name}.npy", maps[name])
        save_map_png(output / f"{name}.png", maps[name],
                     title=f"{name.upper()}  N={count}  m={args.lag}", unit="grey" if name == "s1" else "")

    masks = region_masks(scene)
    print(f"edgedsm demo: {count} frames of {scene.scene.size}x{scene.scene.size} {stack.dtype} "
          f"simulated in {simulated:.1f} s ({count / simulated:.0f} frames/s), "
          f"maps in {computed * 1e3:.0f} ms; effects: {', '.join(simulator.effects)}")
    names = [n for n, m in masks.items() if m.any() and n != "regions"]
    print(f"{'map':<4} " + " ".join(f"{n:>12}" for n in names) + f" {'beta':>8}")
    for name in ESTIMATORS:
        row = " ".join(f"{region_mean(maps[name], masks[n]):12.4f}" for n in names)
        beta = (contrast(maps[name], masks["regions"], masks["background"])
                if masks["regions"].any() and masks["background"].any() else float("nan"))
        print(f"{name:<4} {row} {beta:8.3f}")
    print(f"wrote frames.npy, s1/s2/s3 .npy and .png to {output.resolve()}")
    if not args.daemon:
        return 0
    return run_daemon_demo(args.daemon_config, args.broker, args.time_limit, output / "state", args.dashboard)


def run_daemon_demo(config_path: Path, broker: str | None, time_limit: float, state_dir: Path,
                    dashboard: str = "off") -> int:
    """Part 2: the daemon in a thread, a watch subscriber in this one, until the plate is dry."""
    from edgedsm.config import load_config

    config = load_config(config_path)
    if config.mqtt is None:
        raise EdgedsmError(f"{config_path}: the demo needs an [mqtt] table")
    config.device.state_dir = state_dir
    quiet = logging.getLogger().level >= logging.WARNING
    daemon_log = logging.getLogger("edgedsm")
    previous_level = daemon_log.level
    if quiet:
        daemon_log.setLevel(logging.ERROR)  # the watch lines below tell the story
    try:
        return _daemon_demo(config, config_path, broker, time_limit, dashboard)
    finally:
        daemon_log.setLevel(previous_level)


def _daemon_demo(config: DaemonConfig, config_path: Path, broker: str | None, time_limit: float,
                 dashboard_listen: str = "off") -> int:
    from edgedsm.commands.watcher import Watcher
    from edgedsm.daemon.service import Service
    from edgedsm.localbroker import LocalBroker

    assert config.mqtt is not None
    viewer, dashboard_user = config.mqtt, config.mqtt  # who watches, and the dashboard: as the daemon
    passwords: dict[str, str | None] = {}
    with contextlib.ExitStack() as stack:
        if broker is None and shutil.which("openssl") is None:  # makes the broker's certificates
            local_plain = stack.enter_context(LocalBroker())
            config.mqtt.host, config.mqtt.port = "127.0.0.1", local_plain.port
            print(f"\nedgedsm demo: started a private mosquitto on 127.0.0.1:{local_plain.port}, anonymous "
                  "(openssl is not installed: apt-get install openssl for the TLS broker of docs/security.md)")
        elif broker is None:
            local = stack.enter_context(LocalBroker(secure=True, prefix=config.mqtt.topic_prefix,
                                                    device=config.mqtt.device))
            config.mqtt.host, config.mqtt.port = "localhost", local.port
            config.mqtt.username = f"edgedsm-{config.mqtt.device}"
            config.mqtt.tls = MqttTlsSettings(ca_file=local.ca_file)
            viewer = config.mqtt.model_copy(update={"username": "edgedsm-viewer"})
            dashboard_user = config.mqtt.model_copy(update={"username": "edgedsm-dashboard"})
            passwords = {user: local.passwords[user] for user in ("edgedsm-viewer", "edgedsm-dashboard")}
            # the daemon in this process takes its password as under systemd, from the environment
            stack.enter_context(_environment(PASSWORD_ENV, local.passwords[config.mqtt.username]))
            print(f"\nedgedsm demo: started a private mosquitto on localhost:{local.port} "
                  f"(TLS, passwords and ACLs of config/mosquitto; docs/security.md)")
        else:
            host, _, port = broker.rpartition(":")
            config.mqtt.host, config.mqtt.port = host or "127.0.0.1", int(port)
        print(f"edgedsm demo: daemon on {config.camera.uri} (laser {config.laser.uri if config.laser else 'none'}); "
              f"watching {config.mqtt.topic_prefix}/{config.mqtt.device}/# until the plate is dry\n")
        dashboard = None if dashboard_listen == "off" else _start_dashboard(
            config, config_path, dashboard_listen, dashboard_user, passwords.get("edgedsm-dashboard"))
        if dashboard is not None:
            stack.callback(dashboard.stop)
            print(f"edgedsm demo: plant dashboard at {dashboard.url}")
        service = Service(config_path, config=config)
        thread = threading.Thread(target=service.run, name="edgedsm-demo-daemon", daemon=True)
        thread.start()
        dry = threading.Event()

        def emit(line: str) -> None:
            print(line, flush=True)
            if "alert" in line and re.search(r"-> dry\b(?!ing)", line):
                dry.set()

        watcher = Watcher(viewer, password=passwords.get("edgedsm-viewer"), emit=emit)
        watcher.start()
        try:
            finished = dry.wait(time_limit)
            time.sleep(0.5)
        finally:
            watcher.stop()
            service.stop()
            thread.join(timeout=5)
        if not finished:
            print(f"edgedsm demo: the plate was not dry within {time_limit:g} s", file=sys.stderr)
            return 1
        print("\nedgedsm demo: the plate is dry; daemon stopped, laser off.")
        if dashboard is not None:
            print(f"edgedsm demo: its drying curve: {dashboard.url}", flush=True)
            if sys.stdout.isatty():
                print("edgedsm demo: the dashboard stays up until Ctrl-C", flush=True)
                with contextlib.suppress(KeyboardInterrupt):
                    wait_for(threading.Event())  # until Ctrl-C (in slices: whichever thread takes it)
    return 0


@contextlib.contextmanager
def _environment(name: str, value: str) -> Iterator[None]:
    previous = os.environ.get(name)
    os.environ[name] = value
    try:
        yield
    finally:
        if previous is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = previous


def _start_dashboard(config: DaemonConfig, config_path: Path, listen: str, mqtt: MqttSettings,
                     password: str | None) -> Dashboard:
    """The plant dashboard on the demo's broker, its history beside the daemon's state."""
    from edgedsm.dashboard.app import Dashboard, DashboardSettings

    host, _, port = listen.rpartition(":")
    settings = DashboardSettings(mqtt=mqtt, listen=(host or "127.0.0.1", int(port)),
                                 database=Path(config.device.state_dir) / "dashboard.sqlite3", retention_s=86400.0,
                                 token=None, daemon_configs=[config_path])
    try:
        return Dashboard(settings, password=password).serve_in_background()
    except OSError:  # the port is taken: any free one
        settings.listen = (settings.listen[0], 0)
        return Dashboard(settings, password=password).serve_in_background()
