"""Fixtures shared by the integration tests: real mosquitto brokers, test subscribers, daemon
processes (``daemons``) and a fresh simulated relay board (``sim_board_name``)."""

from __future__ import annotations

import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from helpers_daemon import Daemon
from helpers_mqtt import Broker, Subscriber

from edgedsm.devices.laser import forget_simulated_boards


@pytest.fixture
def make_broker(tmp_path: Path) -> Iterator[Callable[..., Broker]]:
    """Start mosquitto brokers on free loopback ports; all are stopped after the test."""
    brokers: list[Broker] = []

    def make(**kwargs: Any) -> Broker:
        broker = Broker(tmp_path / f"broker{len(brokers)}", **kwargs)
        brokers.append(broker)
        return broker.start()

    yield make
    for broker in brokers:
        broker.stop()


@pytest.fixture
def broker(make_broker: Callable[..., Broker]) -> Broker:
    return make_broker()


@pytest.fixture
def subscribers() -> Iterator[Callable[..., Subscriber]]:
    """Start test subscribers; all are stopped after the test."""
    made: list[Subscriber] = []

    def make(port: int, topics: list[str], **kwargs: Any) -> Subscriber:
        subscriber = Subscriber(port, topics, **kwargs)
        made.append(subscriber)
        return subscriber.start()

    yield make
    for subscriber in made:
        subscriber.stop()


@pytest.fixture
def daemons() -> Iterator[Callable[..., Daemon]]:
    made: list[Daemon] = []

    def start(config: Path, env: dict[str, str] | None = None) -> Daemon:
        daemon = Daemon(config, env)
        made.append(daemon)
        return daemon

    yield start
    for daemon in made:
        daemon.kill()


@pytest.fixture
def sim_board_name() -> Iterator[str]:
    """A fresh process-wide simulated relay board for an in-process daemon."""
    forget_simulated_boards()
    yield f"e2e-{uuid.uuid4().hex[:8]}"
    forget_simulated_boards()
