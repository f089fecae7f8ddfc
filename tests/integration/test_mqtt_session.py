"""The one MQTT connection life cycle (`edgedsm.publish.session.MqttSession`) against a REAL
mosquitto: subscriptions renewed and hooks run once per (re)connection, a close bounded even
while paho sits in a connect attempt, Home Assistant publishing through the JSON link's session
(the broker sees one client for JSON + Home Assistant and one for Sparkplug), and the daemon's
sink set rebuilding Home Assistant with the JSON link and only with it."""

from __future__ import annotations

import json
import re
import socket
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import paho.mqtt.publish as single
import pytest
from helpers_daemon import Daemon, base_config, write_config
from helpers_mqtt import WAIT_S, Broker, Subscriber, wait_until

from edgedsm.publish.session import MqttSession
from edgedsm.publish.settings import MqttSettings
from edgedsm.publish.topics import Topics

pytestmark = [pytest.mark.integration]

PREFIX = "homeassistant"


def _settings(port: int, **overrides: Any) -> MqttSettings:
    values: dict[str, Any] = {"host": "127.0.0.1", "port": port, "device": "line3", "reconnect_min_s": 0.1,
                              "reconnect_max_s": 0.3, "connect_timeout_s": 2.0}
    return MqttSettings(**{**values, **overrides})


class Recorder:
    """Counts a session's hooks and keeps the messages of its subscription (thread-safe)."""

    def __init__(self, session: MqttSession) -> None:
        self.lock = threading.Lock()
        self.counts = {"connected": 0, "ready": 0, "disconnected": 0}
        self.received: list[str] = []
        session.on_connected(lambda: self._count("connected"))
        session.on_ready(lambda: self._count("ready"))
        session.on_disconnected(lambda: self._count("disconnected"))

    def _count(self, event: str) -> None:
        with self.lock:
            self.counts[event] += 1

    def message(self, message: Any) -> None:
        with self.lock:
            self.received.append(message.payload.decode())

    def snapshot(self) -> tuple[dict[str, int], list[str]]:
        with self.lock:
            return dict(self.counts), list(self.received)


@pytest.fixture
def sessions() -> Iterator[Callable[..., MqttSession]]:
    made: list[MqttSession] = []

    def make(settings: MqttSettings, client_id: str = "session-test") -> MqttSession:
        session = MqttSession(settings, client_id=client_id, password="")
        made.append(session)
        return session

    yield make
    for session in made:
        session.close(1.0)


@pytest.mark.timeout(60)
def test_a_reconnection_renews_subscriptions_and_runs_each_hook_once_per_connection(
        broker: Broker, sessions: Callable[..., MqttSession]) -> None:
    session = sessions(_settings(broker.port))
    recorder = Recorder(session)
    session.subscribe("test/in/#", 1, recorder.message, what="test messages")
    session.start()
    session.wait_ready(WAIT_S)
    single.single("test/in/a", b"first", qos=1, hostname="127.0.0.1", port=broker.port)
    wait_until(lambda: recorder.snapshot()[1] == ["first"], WAIT_S, "the first message")
    assert recorder.snapshot()[0] == {"connected": 1, "ready": 1, "disconnected": 0}

    # the broker keeps nothing (no persistence, clean start): only a renewed subscription delivers
    broker.restart()
    wait_until(lambda: session.connects == 2 and session.ready.is_set(), WAIT_S, "the reconnection")
    single.single("test/in/b", b"second", qos=1, hostname="127.0.0.1", port=broker.port)
    wait_until(lambda: recorder.snapshot()[1] == ["first", "second"], WAIT_S, "a message after reconnecting")
    time.sleep(0.5)  # room for a hook run twice to show up
    assert recorder.snapshot()[0] == {"connected": 2, "ready": 2, "disconnected": 1}
    assert (session.connects, session.disconnects, session.last_error) == (2, 1, None)

    # a hook and a subscription added while connected are served at once, once
    late: list[str] = []
    session.on_connected(lambda: late.append("hook"))
    session.subscribe("test/late", 1, lambda message: late.append(message.payload.decode()), what="late messages")
    assert late == ["hook"]
    wait_until(lambda: _subscribed(broker.port, "test/late", late), WAIT_S, "the late subscription")
    assert late.count("hook") == 1 and recorder.snapshot()[0]["connected"] == 2


def _subscribed(port: int, topic: str, received: list[str]) -> bool:
    """Publish a probe on ``topic``; True once one came back (the SUBACK is not awaited)."""
    single.single(topic, b"probe", qos=1, hostname="127.0.0.1", port=port)
    time.sleep(0.1)
    return "probe" in received


@pytest.mark.timeout(60)
def test_close_is_bounded_while_paho_sits_in_a_connect_attempt(sessions: Callable[..., MqttSession]) -> None:
    # A listener whose accept queue is full: the kernel drops further SYNs, so a connect() waits
    # the whole connect timeout, the way it does to a broker behind a dead route.
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen(0)
        port = listener.getsockname()[1]
        fillers = [socket.socket() for _ in range(3)]
        try:
            for filler in fillers:
                filler.setblocking(False)
                filler.connect_ex(("127.0.0.1", port))
            time.sleep(0.2)
            session = sessions(_settings(port, connect_timeout_s=20.0))
            session.start()
            time.sleep(0.5)  # paho's thread is now inside connect()
            assert not session.connected.is_set()
            started = time.monotonic()
            stopped = session.close(0.5)
            took = time.monotonic() - started
        finally:
            for filler in fillers:
                filler.close()
    assert stopped is False, "paho's thread stopped at once: the connect attempt was not under way"
    assert 0.45 <= took < 1.5, took  # 0.5 s asked; an unbounded loop_stop() waits up to 20 s


@pytest.mark.timeout(60)
def test_close_with_the_broker_gone_is_quick_and_complete(broker: Broker,
                                                          sessions: Callable[..., MqttSession]) -> None:
    session = sessions(_settings(broker.port))
    session.start()
    session.wait_ready(WAIT_S)
    broker.stop()
    wait_until(lambda: "cannot reach" in (session.last_error or ""), WAIT_S, "a refused reconnection")
    started = time.monotonic()
    assert session.close(2.0) is True  # paho's thread stopped between two attempts
    assert time.monotonic() - started < 1.0


# -- one client for JSON + Home Assistant, one for Sparkplug ---------------------------------------

def _clients_connected(broker: Broker) -> list[str]:
    """The client id of every connection mosquitto accepted, in order (its notice log)."""
    text = broker.log.read_text(encoding="utf-8", errors="replace") if broker.log.exists() else ""
    return re.findall(r"New client connected from \S+ as (\S+) \(", text)


def _configs(subscriber: Subscriber, prefix: str = PREFIX) -> dict[str, dict[str, Any]]:
    found: dict[str, dict[str, Any]] = {}
    for message in list(subscriber.messages):
        if message.topic.startswith(f"{prefix}/") and message.topic.endswith("/config") and message.payload:
            found[message.topic] = json.loads(message.payload)
    return found


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_home_assistant_uses_the_json_link_and_sparkplug_its_own_session(
        tmp_path: Path, broker: Broker, subscribers: Callable[..., Subscriber],
        daemons: Callable[[Path], Daemon]) -> None:
    from helpers_sparkplug import SparkplugHost

    config = base_config(tmp_path, port=broker.port)
    config["homeassistant"] = {"discovery_prefix": PREFIX}
    config["sparkplug"] = {"group_id": "plant"}
    watcher = subscribers(broker.port, [f"{PREFIX}/#"], client_id="watcher")
    host = SparkplugHost(broker.port).start()
    try:
        daemon = daemons(write_config(tmp_path / "edgedsm.toml", config))
        host.wait_for("NBIRTH", "the Sparkplug birth", timeout=30)  # the daemon's start included
        wait_until(lambda: len(_configs(watcher)) >= 4, 30, "the discovery configs")
        single.single(f"{PREFIX}/status", b"online", hostname="127.0.0.1", port=broker.port)  # HA restarts
        before = len(watcher.messages)
        wait_until(lambda: len([m for m in watcher.messages[before:] if m.topic.endswith("/config")]) >= 4,
                   WAIT_S, "the configs announced again to a restarted Home Assistant")
        daemon_ids = [cid for cid in _clients_connected(broker) if cid.startswith("edgedsm-e2e")]
        assert sorted(daemon_ids) == ["edgedsm-e2e", "edgedsm-e2e-sparkplug"], _clients_connected(broker)
        assert daemon.terminate()[0] == 0
    finally:
        host.stop()


# -- the daemon's sink set: Home Assistant rebuilt with the JSON link, and only with it -------------

@pytest.mark.slow
@pytest.mark.timeout(120)
def test_home_assistant_rebuilt_alone_keeps_the_json_session_and_follows_a_new_one(
        tmp_path: Path, broker: Broker, subscribers: Callable[..., Subscriber]) -> None:
    from edgedsm.config import load_config
    from edgedsm.daemon.sinks import SinkSet
    from edgedsm.publish.homeassistant import HomeAssistantSink
    from edgedsm.publish.json_sink import MqttSink

    topics = Topics.of("edgedsm", "e2e")
    settings = base_config(tmp_path, port=broker.port)
    settings["homeassistant"] = {"discovery_prefix": PREFIX}

    def load(name: str) -> Any:
        return load_config(write_config(tmp_path / name, settings))

    watcher = subscribers(broker.port, [f"{PREFIX}/#", "hass/#", topics.availability], client_id="watcher")
    sinks = SinkSet(lambda name, command: None)
    try:
        assert sinks.apply(load("a.toml")) == ["homeassistant", "mqtt"]
        link, ha = sinks.get("mqtt"), sinks.get("homeassistant")
        assert isinstance(link, MqttSink) and isinstance(ha, HomeAssistantSink) and ha.session is link.session
        wait_until(lambda: len(_configs(watcher)) >= 4, WAIT_S, "the discovery configs")

        # Home Assistant's own settings: it alone is rebuilt, on the running session
        settings["homeassistant"] = {"discovery_prefix": "hass"}
        assert sinks.apply(load("b.toml")) == ["homeassistant"]
        moved = sinks.get("homeassistant")
        assert isinstance(moved, HomeAssistantSink) and moved is not ha and sinks.get("mqtt") is link
        assert moved.session is link.session and link.session.subscriptions() == [
            topics.command_filter, "hass/status"]
        wait_until(lambda: len(_configs(watcher, "hass")) >= 4, WAIT_S, "configs under the new prefix at once")
        assert [m.payload for m in watcher.on(topics.availability)] == [b"online"]
        assert link.session.connects == 1

        # the broker settings: the JSON link is rebuilt, and Home Assistant with it, on the new session
        settings["mqtt"]["keepalive_s"] = 7
        before = len(watcher.messages)
        assert sinks.apply(load("c.toml")) == ["homeassistant", "mqtt"]
        relinked, followed = sinks.get("mqtt"), sinks.get("homeassistant")
        assert isinstance(relinked, MqttSink) and isinstance(followed, HomeAssistantSink)
        assert relinked is not link and link.session.closed and followed.session is relinked.session
        wait_until(lambda: len([m for m in watcher.messages[before:] if m.topic.startswith("hass/")]) >= 4,
                   WAIT_S, "the configs announced on the new session")
        assert [m.payload for m in watcher.on(topics.availability)] == [b"online", b"offline", b"online"]
        json_ids = [cid for cid in _clients_connected(broker) if cid.startswith("edgedsm-e2e")]
        assert json_ids == ["edgedsm-e2e", "edgedsm-e2e"], _clients_connected(broker)  # never a client of HA's

        # Home Assistant removed, then back together with a new broker setting: it waits for the
        # new JSON link instead of attaching to the one about to close
        del settings["homeassistant"]
        assert sinks.apply(load("d.toml")) == ["homeassistant"] and sinks.get("mqtt") is relinked
        assert sinks.get("homeassistant") is None and relinked.session.subscriptions() == [topics.command_filter]
        settings["homeassistant"] = {"discovery_prefix": "hass"}
        settings["mqtt"]["keepalive_s"] = 8
        before = len(watcher.messages)
        assert sinks.apply(load("e.toml")) == ["homeassistant", "mqtt"]
        last, back = sinks.get("mqtt"), sinks.get("homeassistant")
        assert isinstance(last, MqttSink) and isinstance(back, HomeAssistantSink)
        assert relinked.session.closed and back.session is last.session and not last.session.closed
        wait_until(lambda: len([m for m in watcher.messages[before:] if m.topic.startswith("hass/")]) >= 4,
                   WAIT_S, "the configs announced on the newest session")
    finally:
        sinks.close(2.0)
