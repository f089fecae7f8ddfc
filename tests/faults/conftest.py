"""The fault-injection suite: each case makes a real component fail under a running daemon
(`edgedsm run` as a process) and checks what the plant sees and what the laser did.

Fixtures: ``broker`` (a real mosquitto on a free loopback port), ``plant`` (a recording MQTT
subscriber that deduplicates alerts on (stream, seq)), ``relay_board`` (a Numato board emulated
on a socat PTY, recording when the laser really went on and off), ``daemons`` (starts the daemon
on a config; all are killed after the test) and ``fake_gige`` (Aravis' fake GigE Vision camera
as a process). The helpers live in tests/integration/helpers_*.py and helpers_faults.py beside
this file: shared, not copied.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "integration"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from helpers_aravis import FakeGvCamera, fake_gv_cameras
from helpers_daemon import Daemon, write_config
from helpers_faults import NUMATO_CHANNEL, TOPICS, Plant, RecordingNumato, RelayRig
from helpers_mqtt import Broker
from helpers_relay import open_pty_pair


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[Broker]:
    broker = Broker(tmp_path / "broker").start()
    yield broker
    broker.stop()


@pytest.fixture
def plant(broker: Broker) -> Iterator[Plant]:
    subscriber = Plant(broker.port, [TOPICS.availability, TOPICS.state, TOPICS.alerts, TOPICS.stats])
    subscriber.start()
    yield subscriber
    subscriber.stop()


@pytest.fixture
def relay_board(tmp_path: Path) -> Iterator[RelayRig]:
    """A Numato board on a PTY; the test fails if the daemon sent it a single bad byte."""
    with open_pty_pair(tmp_path) as pair:
        board = RecordingNumato(pair.board, NUMATO_CHANNEL)
        board.start()
        try:
            yield RelayRig(board, f"serial:{pair.app}?protocol=numato&channel={NUMATO_CHANNEL}&timeout=0.3")
        finally:
            board.stop()
    assert board.errors == []


@pytest.fixture
def daemons(tmp_path: Path) -> Iterator[Callable[[dict[str, Any]], Daemon]]:
    """Start `edgedsm run` on a config (written to tmp_path/daemon.toml); all killed afterwards."""
    made: list[Daemon] = []

    def start(config: dict[str, Any]) -> Daemon:
        daemon = Daemon(write_config(tmp_path / "daemon.toml", config))
        made.append(daemon)
        return daemon

    yield start
    for daemon in made:
        daemon.kill()


@pytest.fixture
def fake_gige(tmp_path: Path) -> Iterator[Callable[..., FakeGvCamera]]:
    """Aravis' fake GigE Vision cameras on loopback, killed after the test."""
    yield from fake_gv_cameras(tmp_path)
