"""Fixtures shared by the integration tests: real mosquitto brokers and test subscribers."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from helpers_mqtt import Broker, Subscriber


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
