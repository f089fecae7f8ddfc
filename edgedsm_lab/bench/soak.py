"""Soak under faults: the daemon as a process, faults injected in a loop for M minutes.

Real parts: a mosquitto with persistence on a free loopback port, a Numato relay board emulated on a
socat PTY pair (recording when its contact really moved), `edgedsm run` on the simulated drying
plate, and a plant subscriber with a persistent session that deduplicates alerts on (stream, seq).

Faults, in turn: the relay answers garbage while ON (then mended), the broker stops and starts
again, a SIGHUP with a bad file (then the good one back), a burst of 50 commands, SIGKILL of the
daemon and a restart on the same state directory. After each the loop waits until the daemon
measures again. The table gives the faults injected by kind, the worst laser-off delay (fault →
contact open) against its bound, alerts lost (gaps in seq after dedup), and the daemon's RSS drift
(the longest-lived process: its first sample after warm-up against its last).

Needs mosquitto and socat. Prints the table; ``-o docs/bench-soak.md`` writes it.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import random
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from edgedsm.daemon.acquisition import OFF_RETRY, RELAY_CHECK_S
from edgedsm.errors import EdgedsmError
from edgedsm.localbroker import free_port
from edgedsm.publish.command_auth import sign
from edgedsm.resources import data_file
from edgedsm_lab.bench.report import Report, add_output_argument, load_average

HELP = "faults in a loop against the daemon: alerts lost, laser-off delays, memory drift"
DEVICE = "soak"
CHANNEL = 11
RELAY_TIMEOUT_S = 0.3
#: Laser-off bound per fault kind (s): a broken relay is noticed at the next readback check; after
#: a SIGKILL the restarted daemon switches off first (a plant's unit also runs `laser off` at once).
BOUNDS_S = {"relay garbage": RELAY_CHECK_S + RELAY_TIMEOUT_S + OFF_RETRY.initial + 1.5, "daemon SIGKILL": 15.0}
RSS_WARMUP_S = 5.0
WAIT_S = 30.0
START_WAIT_S = 90.0  # a daemon's start includes compiling its kernels: slow on a loaded machine


def _tool(name: str) -> str:
    path = shutil.which(name) or shutil.which(name, path="/usr/sbin:/usr/bin:/sbin")
    if path is None:
        raise EdgedsmError(f"{name} is not installed: the soak needs it (Debian: apt-get install {name})")
    return path


def _wait(predicate: Callable[[], bool], timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise EdgedsmError(f"soak: timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(0.02)


class Mosquitto:
    """mosquitto with persistence (saved at SIGTERM), same port across restarts."""

    def __init__(self, directory: Path) -> None:
        self.port = free_port()
        self.conf = directory / "mosquitto.conf"
        lines = [f"listener {self.port} 127.0.0.1", "allow_anonymous true", "persistence true",
                 f"persistence_location {directory}/", "autosave_interval 1"]
        if os.geteuid() == 0:
            lines.append("user root")
        self.conf.write_text("\n".join(lines) + "\n")
        self.process: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        self.process = subprocess.Popen([_tool("mosquitto"), "-c", str(self.conf)], stdout=subprocess.DEVNULL,
                                        stderr=subprocess.DEVNULL)

        def accepts() -> bool:
            with socket.socket() as sock:
                return sock.connect_ex(("127.0.0.1", self.port)) == 0
        _wait(accepts, 10, "mosquitto to listen")

    def stop(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.terminate()
            self.process.wait(10)
        self.process = None


class NumatoBoard(threading.Thread):
    """A Numato board on the far end of a PTY; ``garbage`` makes it answer nonsense (it still switches)."""

    def __init__(self, path: str) -> None:
        super().__init__(daemon=True, name="soak-numato")
        import serial

        self.port = serial.Serial(path, timeout=0.02)
        self.garbage = False
        self.is_on = False
        self.changes: list[tuple[float, bool]] = []  # (monotonic, on) when the contact moved
        self._halt = threading.Event()

    def run(self) -> None:
        buffer = bytearray()
        token = chr(55 + CHANNEL)
        while not self._halt.is_set():
            try:
                buffer += self.port.read(max(1, self.port.in_waiting))
            except OSError:
                return
            while b"\r" in buffer:
                end = buffer.index(b"\r")
                command, buffer = buffer[:end].decode("ascii", "replace"), buffer[end + 1:]
                reply = command.encode() + b"\n\r"
                if command in (f"relay on {token}", f"relay off {token}"):
                    on = command.startswith("relay on")
                    if on != self.is_on:
                        self.is_on = on
                        self.changes.append((time.monotonic(), on))
                elif command == f"relay read {token}":
                    reply += (b"on" if self.is_on else b"off") + b"\n\r"
                self.port.write(b"\x5a\xa5\x13\x37" + reply[::-1] if self.garbage else reply + b">")

    def off_after(self, t: float) -> float | None:
        return next((c for c, on in self.changes if not on and c > t), None)

    def stop(self) -> None:
        self._halt.set()
        self.join(3)
        self.port.close()


@dataclass
class Plant:
    """A SCADA-like subscriber with a persistent session: alerts and stats."""

    port: int
    base: str
    alerts: dict[tuple[str, int], dict[str, Any]] = field(default_factory=dict)
    copies: int = 0
    last_stats: dict[str, Any] = field(default_factory=dict)

    def start(self) -> Plant:
        import paho.mqtt.client as mqtt
        from paho.mqtt.enums import CallbackAPIVersion

        self.client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="soak-plant", clean_session=False)
        self.client.reconnect_delay_set(0.05, 0.3)
        self.client.on_connect = lambda c, *a: c.subscribe([(f"{self.base}/alerts", 1), (f"{self.base}/stats", 1)])
        self.client.on_message = self._message
        self.client.connect_async("127.0.0.1", self.port, keepalive=10)
        self.client.loop_start()
        return self

    def _message(self, client: Any, userdata: Any, message: Any) -> None:
        data = json.loads(message.payload)
        if message.topic.endswith("/alerts"):
            self.copies += 1
            self.alerts[(data["stream"], data["seq"])] = data
        else:
            self.last_stats = data

    def measuring(self, after_frames: int) -> bool:
        stats = self.last_stats
        return (stats.get("frames", -1) > after_frames and stats.get("laser") == "on"
                and stats.get("state", {}).get("plate") in ("wet", "drying", "dry"))

    def frames(self) -> int:
        return int(self.last_stats.get("frames", -1))

    def lost(self) -> int:
        """Gaps in seq per stream, after deduplication."""
        by_stream: dict[str, list[int]] = defaultdict(list)
        for stream, seq in self.alerts:
            by_stream[stream].append(seq)
        return sum(max(seqs) - len(seqs) for seqs in by_stream.values())

    def stop(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


def _toml(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    return json.dumps(str(value)) if isinstance(value, str | Path) else repr(value)


def write_config(path: Path, tables: dict[str, Any]) -> None:
    lines = []
    for name, table in tables.items():
        lines.append(f"[[{name}]]" if name == "regions" else f"[{name}]")
        lines += [f"{key} = {_toml(value)}" for key, value in table.items()] + [""]
    partial = path.with_suffix(".partial")
    partial.write_text("\n".join(lines), encoding="utf-8")
    partial.replace(path)


class Rig:
    """Broker, relay board, plant and the daemon process in one temporary directory."""

    def __init__(self, directory: Path) -> None:
        self.directory = directory
        self.broker = Mosquitto(directory)
        self.broker.start()
        app, board = directory / "app", directory / "board"
        self.socat = subprocess.Popen([_tool("socat"), f"pty,raw,echo=0,link={app}", f"pty,raw,echo=0,link={board}"],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        _wait(lambda: app.exists() and board.exists(), 10, "socat's PTYs")
        self.board = NumatoBoard(str(board))
        self.board.start()
        self.plant = Plant(self.broker.port, f"edgedsm/{DEVICE}").start()
        self.config = directory / "daemon.toml"
        self.tables = {
            "device": {"name": DEVICE, "state_dir": directory / "state"},
            "camera": {"uri": f"sim:{data_file('config/scenes/drying_demo.toml')}?time_scale=0.2",
                       "grab_timeout_s": 2.0},
            "laser": {"uri": f"serial:{app}?protocol=numato&channel={CHANNEL}&timeout={RELAY_TIMEOUT_S}"},
            "acquisition": {"dark_frames": 2, "dark_every_min": 0},
            "estimator": {"activity": "s2", "window": 100, "lag": 5, "q": 1.0},
            "regions": {"name": "plate", "wet_above": 0.30, "dry_below": 0.16, "hysteresis": 0.05, "min_dwell_s": 1.0},
            "cadence": {"stats_interval_s": 0.5, "maps_interval_s": 600.0},
            "mqtt": {"host": "127.0.0.1", "port": self.broker.port, "keepalive_s": 5, "reconnect_min_s": 0.1,
                     "reconnect_max_s": 0.5},
            "logging": {"level": "info"},
        }
        write_config(self.config, self.tables)
        self.daemon: subprocess.Popen[bytes] | None = None
        self.command_key = secrets.token_hex(32)  # the daemon's command key; command_burst signs with it
        self.rss: dict[int, list[tuple[float, int]]] = defaultdict(list)  # pid -> (monotonic, kB)

    def start_daemon(self) -> None:
        self.daemon = subprocess.Popen([sys.executable, "-m", "edgedsm", "run", "-c", str(self.config)],
                                       stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                       stderr=open(self.directory / "daemon.log", "ab"),  # noqa: SIM115
                                       env={**os.environ, "EDGEDSM_COMMAND_KEY": f"soak {self.command_key}"})
        self.plant.last_stats = {}  # a new process counts its frames from 0
        self.wait_measuring(START_WAIT_S)

    def wait_measuring(self, timeout: float = WAIT_S) -> None:
        frames = self.plant.frames()
        try:
            _wait(lambda: self.plant.measuring(frames) and self.board.is_on, timeout, "the daemon measuring")
        except EdgedsmError as exc:
            tail = (self.directory / "daemon.log").read_text(errors="replace").splitlines()[-15:]
            raise EdgedsmError("\n".join([str(exc), "the daemon's log ends:", *tail])) from exc

    def sample_rss(self) -> None:
        if self.daemon is None:
            return
        with contextlib.suppress(OSError, ValueError):
            for line in Path(f"/proc/{self.daemon.pid}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    self.rss[self.daemon.pid].append((time.monotonic(), int(line.split()[1])))

    def rss_drift(self) -> tuple[int, int, float]:
        """(first kB after warm-up, last kB, hours sampled) of the longest-lived process."""
        samples = max(self.rss.values(), key=lambda s: s[-1][0] - s[0][0])
        warm = [s for s in samples if s[0] >= samples[0][0] + RSS_WARMUP_S] or samples
        return warm[0][1], warm[-1][1], (warm[-1][0] - warm[0][0]) / 3600

    def close(self) -> int | None:
        code = None
        if self.daemon is not None and self.daemon.poll() is None:
            self.daemon.send_signal(signal.SIGTERM)
            code = self.daemon.wait(20)
        time.sleep(0.5)  # the last alerts in flight
        self.plant.stop()
        self.board.stop()
        self.socat.terminate()
        self.socat.wait(5)
        self.broker.stop()
        return code


# -- the faults: each returns the laser-off delay it caused (s), or None ---------------------------

def relay_garbage(rig: Rig, rng: random.Random) -> float | None:
    broken = time.monotonic()
    rig.board.garbage = True
    _wait(lambda: rig.board.off_after(broken) is not None, BOUNDS_S["relay garbage"] + 10, "the relay off")
    time.sleep(rng.uniform(0.5, 2.0))
    rig.board.garbage = False
    rig.wait_measuring()
    off = rig.board.off_after(broken)
    return None if off is None else off - broken


def broker_restart(rig: Rig, rng: random.Random) -> float | None:
    rig.broker.stop()
    time.sleep(rng.uniform(0.5, 2.0))
    rig.broker.start()
    rig.wait_measuring()
    return None


def bad_reload(rig: Rig, rng: random.Random) -> float | None:
    assert rig.daemon is not None
    bad = rng.choice([b"\xff\xfe not UTF-8", b"", b"[device]\nname = 3\n"])
    rig.config.write_bytes(bad)
    rig.daemon.send_signal(signal.SIGHUP)
    time.sleep(1.0)
    write_config(rig.config, rig.tables)
    rig.wait_measuring()
    return None


def command_burst(rig: Rig, rng: random.Random) -> float | None:
    client = rig.plant.client

    def signed(name: str, arguments: dict[str, Any]) -> dict[str, Any]:  # as an operator's edgedsm cmd would
        topic = f"edgedsm/{DEVICE}/cmd/{name}"
        return sign("soak", rig.command_key.encode(), topic, arguments, now=time.time())

    for i in range(50):
        name = rng.choice(["laser", "dark", "rebaseline", "laser"])
        payload = {"request_id": i, **signed(name, {"state": rng.choice(["on", "off", "auto"])} if name == "laser"
                                             else {})}
        client.publish(f"edgedsm/{DEVICE}/cmd/{name}", json.dumps(payload) if rng.random() > 0.1 else b"\x00{", qos=1)
        time.sleep(0.01)
    time.sleep(1.0)
    for _ in range(20):  # hand the laser back to the plan (a rate-limited `auto` is refused: again)
        client.publish(f"edgedsm/{DEVICE}/cmd/laser", json.dumps(signed("laser", {"state": "auto"})), qos=1)
        time.sleep(0.6)
        if rig.plant.last_stats.get("laser") == "on":
            break
    rig.wait_measuring()
    return None


def daemon_sigkill(rig: Rig, rng: random.Random) -> float | None:
    assert rig.daemon is not None
    time.sleep(rng.uniform(0.0, 1.0))
    rig.daemon.kill()
    killed = time.monotonic()
    rig.daemon.wait(10)
    rig.start_daemon()
    off = rig.board.off_after(killed)
    return None if off is None else off - killed


FAULTS: dict[str, Callable[[Rig, random.Random], float | None]] = {
    "relay garbage": relay_garbage, "broker restart": broker_restart, "bad SIGHUP reload": bad_reload,
    "command burst": command_burst, "daemon SIGKILL": daemon_sigkill,
}


@dataclass
class SoakResult:
    minutes: float
    injected: dict[str, int]
    worst_off_s: dict[str, float]
    alerts: int
    copies: int
    lost: int
    rss_first_kb: int
    rss_last_kb: int
    rss_hours: float
    exit_code: int | None

    @property
    def within_bounds(self) -> bool:
        return all(self.worst_off_s.get(kind, 0.0) <= bound for kind, bound in BOUNDS_S.items())


def fault_due(kind: str, turn: int, kill_every: int) -> bool:
    """Whether fault ``kind`` is injected at ``turn`` (counted over all kinds in turn): every one
    each round, but a SIGKILL only every ``kill_every``-th round (the first included), so that one
    daemon process lives through that many rounds of the other faults and its RSS drift covers them."""
    return kind != "daemon SIGKILL" or (turn // len(FAULTS)) % kill_every == 0


def soak(minutes: float, seed: int = 1, progress: Callable[[str], None] = lambda _: None,
         kill_every: int = 1) -> SoakResult:
    """Run the faults in turn until ``minutes`` are over (every kind at least once; a SIGKILL
    every ``kill_every``-th round, see :func:`fault_due`)."""
    if kill_every < 1:
        raise ValueError(f"kill_every must be at least 1, got {kill_every}")
    rng = random.Random(seed)
    injected: dict[str, int] = defaultdict(int)
    worst: dict[str, float] = {}
    with tempfile.TemporaryDirectory(prefix="edgedsm-soak-") as tmp:
        rig = Rig(Path(tmp))
        try:
            rig.start_daemon()
            started = time.monotonic()
            sampler_stop = threading.Event()

            def sample() -> None:
                while not sampler_stop.wait(1.0):
                    rig.sample_rss()
            sampler = threading.Thread(target=sample, daemon=True)
            sampler.start()
            kinds = list(FAULTS)
            turn = 0
            while turn < len(kinds) or time.monotonic() - started < minutes * 60:
                kind = kinds[turn % len(kinds)]
                if not fault_due(kind, turn, kill_every):
                    turn += 1
                    continue
                delay = FAULTS[kind](rig, rng)
                injected[kind] += 1
                if delay is not None:
                    worst[kind] = max(worst.get(kind, 0.0), delay)
                progress(f"{time.monotonic() - started:6.1f} s  {kind}" + ("" if delay is None else f": laser off "
                                                                            f"after {delay:.2f} s"))
                turn += 1
            sampler_stop.set()
            sampler.join(2)
        finally:
            code = rig.close()
        first, last, hours = rig.rss_drift()
        return SoakResult((time.monotonic() - started) / 60, dict(injected), worst, len(rig.plant.alerts),
                          rig.plant.copies, rig.plant.lost(), first, last, hours, code)


def _rounds(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"a whole number of rounds, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--minutes", type=float, default=5.0, help="how long to inject faults (default 5)")
    parser.add_argument("--seed", type=int, default=1, help="random seed of the fault timings")
    parser.add_argument("--kill-every", type=_rounds, default=1, metavar="K",
                        help="SIGKILL the daemon every K-th round of faults only, the first included "
                             "(default 1: every round); a large K lets one daemon process live through the "
                             "other faults, so the RSS drift covers them (a leak per reload, reconnection ...)")
    add_output_argument(parser, "docs/bench-soak.md")


def report_lines(result: SoakResult, report: Report) -> None:
    report.table(["fault", "injected", "worst laser-off delay (s)", "bound (s)"],
                 [[kind, result.injected.get(kind, 0),
                   f"{result.worst_off_s[kind]:.2f}" if kind in result.worst_off_s else "-",
                   f"{BOUNDS_S[kind]:.1f}" if kind in BOUNDS_S else "-"] for kind in FAULTS])
    report.line()
    drift = result.rss_last_kb - result.rss_first_kb
    report.table(["alerts (distinct)", "copies received", "alerts lost", "RSS first (MB)", "RSS last (MB)",
                  "RSS drift (MB)", "exit code"],
                 [[result.alerts, result.copies, result.lost, f"{result.rss_first_kb / 1024:.1f}",
                   f"{result.rss_last_kb / 1024:.1f}", f"{drift / 1024:+.1f}", result.exit_code]])


def run(args: argparse.Namespace) -> int:
    load = load_average()
    result = soak(args.minutes, args.seed, progress=lambda text: print(text, flush=True), kill_every=args.kill_every)
    report = Report("Soak under faults")
    every = f" --kill-every {args.kill_every}" if args.kill_every != 1 else ""
    report.line(report.machine(f"edgedsm bench soak --minutes {args.minutes:g}{every}", load=load,
                               load_after=load_average())
                + f" {result.minutes:.1f} minutes of faults in turn (seed {args.seed}); RSS of the longest-lived "
                  f"daemon process over {result.rss_hours * 60:.1f} minutes.")
    report.line()
    report_lines(result, report)
    report.line()
    if args.output:
        report.save(args.output)
    return 0 if result.lost == 0 and result.within_bounds and result.exit_code == 0 else 1
