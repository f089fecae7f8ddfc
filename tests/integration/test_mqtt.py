"""MqttSink (the daemon's MQTT link) and `edgedsm watch` against a REAL mosquitto on a free loopback port.

Each test starts its own broker from a config file in tmp_path (persistence off unless the test
is about surviving a broker restart, TLS and passwords only where a test is about them) and
stops it in a finalizer. Publishers that must die uncleanly run in a child process that is
killed with SIGKILL.

Alert delivery is checked the way a subscriber must consume it: at least once, deduplicated on
(stream, seq), so "exactly once" below means exactly once after that deduplication (documented
in edgedsm.publish.mqtt). Payloads are read back as the typed messages of edgedsm.messages.
Across a broker restart the broker keeps sessions (persistence on) and
the subscriber uses a persistent session, as a real SCADA subscriber must.

mosquitto, mosquitto_passwd and openssl are required: without them these tests FAIL (the
README's test command installs them).
"""

from __future__ import annotations

import contextlib
import gc
import json
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import paho.mqtt.client as mqtt
import pytest
from helpers_commands import KEY_TEXT, signed
from helpers_mqtt import WAIT_S, Broker, TlsFiles, child_env, make_certificates, tool, wait_until
from paho.mqtt.enums import CallbackAPIVersion
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties

from edgedsm.errors import ConfigError
from edgedsm.messages import Alert, AlertKind, MapFrame, RegionState, StateReport, Stats
from edgedsm.publish import (
    LaserCommand,
    MqttSettings,
    MqttSink,
    PublishError,
    Topics,
    decode_map,
    downsample_map,
)

pytestmark = [pytest.mark.integration, pytest.mark.timeout(60)]


# the broker and subscriber fixtures (make_broker, broker, subscribers) are in conftest.py


# -- publishers ------------------------------------------------------------------------------

def _settings(port: int, **kwargs: Any) -> MqttSettings:
    values: dict[str, Any] = {"host": "127.0.0.1", "port": port, "device": "cam0", "keepalive_s": 5,
                              "reconnect_min_s": 0.05, "reconnect_max_s": 0.3, "connect_timeout_s": 2.0,
                              "shutdown_timeout_s": 1.0}
    values.update(kwargs)
    return MqttSettings.model_validate(values)


@pytest.fixture
def publishers(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Callable[..., MqttSink]]:
    made: list[MqttSink] = []
    monkeypatch.setenv("EDGEDSM_COMMAND_KEY", KEY_TEXT)  # the publishers accept the tests' signed commands

    def make(settings: MqttSettings, state_dir: Path | None = None, **kwargs: Any) -> MqttSink:
        publisher = MqttSink(settings, state_dir or tmp_path / "state", **kwargs)
        made.append(publisher)
        return publisher.start()

    yield make
    for publisher in made:
        publisher.close(settings_close_s(publisher))


def settings_close_s(sink: MqttSink) -> float:
    return sink.publisher.settings.shutdown_timeout_s + 0.5


def _alert(kind: str = "fault", **fields: Any) -> Alert:
    return Alert(kind=AlertKind(kind), t=time.time(), **fields)


def _state(**regions: str) -> StateReport:
    now = time.time()
    return StateReport(t=now, estimator="s2", regions={name: RegionState(region=name, state=state, since=now)
                                                       for name, state in regions.items()})


def _alerts(subscriber: Any) -> list[Alert]:
    return [Alert.model_validate_json(m.payload) for m in subscriber.on(TOPICS.alerts)]


def _region_state(message: Any, region: str) -> str:
    return StateReport.model_validate_json(message.payload).regions[region].state


CHILD = textwrap.dedent("""
    # A publisher in its own process, driven line by line on stdin, so a test can kill -9 it.
    import json, sys
    from edgedsm.messages import Alert, StateReport
    from edgedsm.publish import MqttSettings, MqttSink
    config = json.loads(sys.argv[1])
    publisher = MqttSink(MqttSettings.model_validate(config["settings"]), config["state_dir"]).start()
    print("ready", flush=True)
    for line in sys.stdin:
        verb, _, rest = line.strip().partition(" ")
        if verb == "connected":
            publisher.wait_connected(10)
            print("connected", flush=True)
        elif verb == "alert":
            print("seq", publisher.publish_alert(Alert.model_validate_json(rest)), flush=True)
        elif verb == "state":
            publisher.publish_state(StateReport.model_validate_json(rest))
            print("ok", flush=True)
        elif verb == "flush":
            print("flushed", publisher.flush_alerts(10), flush=True)
        elif verb == "close":
            publisher.close(2.0)
            print("closed", flush=True)
            break
""")


class Child:
    """A publisher process (see CHILD) and its line protocol."""

    def __init__(self, tmp_path: Path, settings: MqttSettings, state_dir: Path) -> None:
        script = tmp_path / "child_publisher.py"
        script.write_text(CHILD)
        config = {"settings": settings.model_dump(mode="json"), "state_dir": str(state_dir)}
        self.process = subprocess.Popen([sys.executable, str(script), json.dumps(config)], stdin=subprocess.PIPE,
                                        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                        env=child_env())
        self._expect("ready")

    def _expect(self, prefix: str, timeout: float = WAIT_S) -> str:
        assert self.process.stdout is not None
        result: list[str] = []
        reader = threading.Thread(target=lambda: result.append(self.process.stdout.readline()), daemon=True)
        reader.start()
        reader.join(timeout)
        line = result[0].strip() if result else ""
        if not line.startswith(prefix):
            self.kill()
            err = self.process.stderr.read() if self.process.stderr else ""
            pytest.fail(f"publisher child said {line!r}, expected {prefix!r}; stderr:\n{err}")
        return line

    def send(self, line: str, expect: str) -> str:
        assert self.process.stdin is not None
        self.process.stdin.write(line + "\n")
        self.process.stdin.flush()
        return self._expect(expect)

    def alert(self, alert: Alert) -> int:
        return int(self.send(f"alert {alert.to_bytes().decode()}", "seq").split()[1])

    def kill(self) -> None:
        if self.process.poll() is None:
            os.kill(self.process.pid, signal.SIGKILL)
        self.process.wait(timeout=10)

    def close_pipes(self) -> None:
        for pipe in (self.process.stdin, self.process.stdout, self.process.stderr):
            if pipe is not None:
                with contextlib.suppress(OSError):
                    pipe.close()


@pytest.fixture
def children(tmp_path: Path) -> Iterator[Callable[[MqttSettings, Path], Child]]:
    made: list[Child] = []

    def make(settings: MqttSettings, state_dir: Path) -> Child:
        child = Child(tmp_path, settings, state_dir)
        made.append(child)
        return child

    yield make
    for child in made:
        child.kill()
        child.close_pipes()


TOPICS = Topics.of("edgedsm", "cam0")


def _distinct(alerts: list[Alert]) -> dict[tuple[str, int], Alert]:
    return {(a.stream or "", a.seq or 0): a for a in alerts}


# -- availability ----------------------------------------------------------------------------

def test_online_then_last_will_offline_when_killed(broker, subscribers, children, tmp_path):
    subscriber = subscribers(broker.port, [TOPICS.availability])
    child = children(_settings(broker.port), tmp_path / "state")
    child.send("connected", "connected")
    subscriber.wait_for(TOPICS.availability, lambda m: m.payload == b"online", "online")
    child.kill()  # no DISCONNECT: the broker must send the last will
    subscriber.wait_for(TOPICS.availability, lambda m: m.payload == b"offline", "the last will 'offline'",
                        timeout=10)
    # and it is retained: a newcomer learns the device is offline
    late = subscribers(broker.port, [TOPICS.availability])
    late.wait_for(TOPICS.availability, lambda m: m.payload == b"offline" and m.retain, "retained offline")


def test_clean_close_publishes_offline_quickly(broker, subscribers, publishers):
    subscriber = subscribers(broker.port, [TOPICS.availability])
    publisher = publishers(_settings(broker.port))
    publisher.wait_connected(WAIT_S)
    subscriber.wait_for(TOPICS.availability, lambda m: m.payload == b"online", "online")
    started = time.monotonic()
    publisher.close(1.5)
    assert time.monotonic() - started < 2.0
    subscriber.wait_for(TOPICS.availability, lambda m: m.payload == b"offline", "offline after close")


def test_mqtt_3_1_1_works_too(broker, subscribers, publishers):
    subscriber = subscribers(broker.port, [TOPICS.availability, TOPICS.alerts, f"{TOPICS.base}/cmd/+/reply"])
    publisher = publishers(_settings(broker.port, protocol="3.1.1"), on_command=lambda name, command: None)
    publisher.wait_connected(WAIT_S)
    subscriber.wait_for(TOPICS.availability, lambda m: m.payload == b"online", "online")
    publisher.publish_alert(_alert("fault", region="A"))
    assert publisher.flush_alerts(WAIT_S)
    subscriber.client.publish(TOPICS.command("dark"), signed(TOPICS.command("dark"), request_id=1), qos=1)
    reply = subscriber.wait_for(TOPICS.reply("dark"), lambda m: True, "reply").json()
    assert reply["ok"] is True and reply["request_id"] == 1 and reply["result"] is None
    assert [a.seq for a in _alerts(subscriber)] == [1]


# -- retained state --------------------------------------------------------------------------

def test_retained_state_republished_after_broker_restart(broker, subscribers, publishers):
    publisher = publishers(_settings(broker.port))
    publisher.wait_connected(WAIT_S)
    publisher.publish_state(_state(A="wet"))
    first = subscribers(broker.port, [TOPICS.state])
    first.wait_for(TOPICS.state, lambda m: _region_state(m, "A") == "wet", "state wet")
    first.stop()

    broker.stop()  # persistence off: the broker forgets every retained message
    wait_until(lambda: not publisher.connected, 5, "the publisher to notice the broker is gone")
    publisher.publish_state(_state(A="drying"))  # while down
    broker.start()
    publisher.wait_connected(WAIT_S)

    late = subscribers(broker.port, [TOPICS.state, TOPICS.availability])
    state = late.wait_for(TOPICS.state, lambda m: m.retain, "retained state after the restart")
    assert _region_state(state, "A") == "drying"  # the newest, not the one before the outage
    late.wait_for(TOPICS.availability, lambda m: m.payload == b"online" and m.retain, "retained online")
    assert publisher.counters()["connects"] == 2


# -- alerts ----------------------------------------------------------------------------------

def test_every_alert_exactly_once_across_broker_restart(make_broker, subscribers, publishers):
    broker = make_broker(persistence=True)
    subscriber = subscribers(broker.port, [TOPICS.alerts], client_id="scada-1")  # persistent session
    publisher = publishers(_settings(broker.port))
    publisher.wait_connected(WAIT_S)

    total = 60
    produced: list[int] = []

    def produce() -> None:
        for i in range(total):
            produced.append(publisher.publish_alert(_alert("transition", region="A", reason=f"i={i}")))
            time.sleep(0.02)

    producer = threading.Thread(target=produce)
    producer.start()
    wait_until(lambda: len(produced) >= total // 3, 10, "the first alerts")
    broker.restart()  # in mid-run: some alerts in flight, some queued while it is down
    producer.join(timeout=20)
    assert len(produced) == total and produced == list(range(1, total + 1))

    wait_until(lambda: len(_distinct(_alerts(subscriber))) >= total, WAIT_S, f"{total} distinct alerts")
    assert publisher.flush_alerts(WAIT_S)
    distinct = _distinct(_alerts(subscriber))
    assert sorted(seq for _, seq in distinct) == produced
    assert len({stream for stream, _ in distinct}) == 1
    assert all(distinct[key].reason == f"i={key[1] - 1}" for key in distinct)
    assert publisher.pending_alerts == 0 and publisher.counters()["connects"] >= 2


def test_every_alert_exactly_once_across_publisher_kill_and_restart(make_broker, subscribers, children,
                                                                     tmp_path):
    broker = make_broker(persistence=True)
    subscriber = subscribers(broker.port, [TOPICS.alerts], client_id="scada-2")
    state_dir = tmp_path / "state"
    settings = _settings(broker.port)

    first = children(settings, state_dir)
    first.send("connected", "connected")
    sent = [first.alert(_alert("transition", reason=f"n={n}")) for n in range(3)]
    assert first.send("flush", "flushed") == "flushed True"

    broker.stop()  # now alerts can only be stored, not sent...
    sent += [first.alert(_alert("transition", reason=f"n={n}")) for n in range(3, 6)]
    first.kill()   # ...and the daemon dies before the broker ever saw them
    broker.start()

    second = children(settings, state_dir)  # the restarted daemon, same state directory
    second.send("connected", "connected")
    sent += [second.alert(_alert("transition", reason=f"n={n}")) for n in range(6, 8)]
    assert sent == list(range(1, 9))  # seq continues across the restart
    assert second.send("flush", "flushed") == "flushed True"

    wait_until(lambda: len(_distinct(_alerts(subscriber))) >= 8, WAIT_S, "8 distinct alerts")
    distinct = _distinct(_alerts(subscriber))
    assert sorted(seq for _, seq in distinct) == sent
    assert [distinct[k].reason for k in sorted(distinct, key=lambda k: k[1])] == [f"n={n}" for n in range(8)]
    second.send("close", "closed")


def test_alerts_published_before_the_broker_exists_are_delivered(tmp_path, subscribers, publishers):
    late_broker = Broker(tmp_path / "late")  # not started yet
    try:
        publisher = publishers(_settings(late_broker.port))
        seqs = [publisher.publish_alert(_alert("fault", region="A")) for _ in range(3)]
        time.sleep(0.3)
        with pytest.raises(PublishError, match=f"cannot reach 127.0.0.1:{late_broker.port}"):
            publisher.wait_connected(0.5)
        late_broker.start()
        subscriber = subscribers(late_broker.port, [TOPICS.alerts])
        publisher.wait_connected(WAIT_S)
        wait_until(lambda: len(_alerts(subscriber)) >= 3, WAIT_S, "3 alerts")
        assert [a.seq for a in _alerts(subscriber)] == seqs
    finally:
        late_broker.stop()


# -- maps ------------------------------------------------------------------------------------

def test_maps_decode_within_one_quantization_step(broker, subscribers, publishers):
    subscriber = subscribers(broker.port, [TOPICS.maps_filter, f"{TOPICS.maps_filter}/meta"])
    publisher = publishers(_settings(broker.port, map_max_size=128))
    publisher.wait_connected(WAIT_S)
    rng = np.random.default_rng(5)
    big = rng.gamma(2.0, 0.1, size=(300, 200))   # downsampled to 128 x 85
    small = rng.random((40, 60)) * 1e-3           # sent as is
    publisher.publish_map(MapFrame("s1", big, seq=1234, t=1.7e9, window=200, lag=10))
    publisher.publish_map(MapFrame("s3", small, seq=1234, t=1.7e9, window=200, lag=10))
    flat = np.full((16, 16), 0.25)
    publisher.publish_map(MapFrame("s2", flat, seq=99, t=1.7e9, window=200, lag=10, extra={"region": "all"}))

    for name, source in (("s1", big), ("s3", small), ("s2", flat)):
        png = subscriber.wait_for(TOPICS.map(name), lambda m: True, f"map {name}").payload
        meta = subscriber.wait_for(TOPICS.map_meta(name), lambda m: True, f"meta of {name}").json()
        decoded = decode_map(png, meta)
        expected = downsample_map(source, 128)
        assert decoded.shape == expected.shape == tuple(meta["shape"])
        assert np.abs(decoded - expected).max() <= meta["scale"] / 2 + 1e-12 * np.abs(expected).max()
        assert meta["window"] == 200 and meta["lag"] == 10
    assert subscriber.on(TOPICS.map_meta("s1"))[-1].json()["downsampled"] is True
    assert subscriber.on(TOPICS.map_meta("s1"))[-1].json()["seq"] == 1234
    s2_meta = subscriber.on(TOPICS.map_meta("s2"))[-1].json()
    assert s2_meta["seq"] == 99 and s2_meta["region"] == "all" and s2_meta["estimator"] == "s2"
    wait_until(lambda: publisher.counters()["maps_sent"] == 3, 5, "3 maps counted as sent")


def test_stats_carry_the_publisher_counters_and_no_nan(broker, subscribers, publishers):
    subscriber = subscribers(broker.port, [TOPICS.stats])
    publisher = publishers(_settings(broker.port))
    publisher.wait_connected(WAIT_S)
    publisher.publish_stats(Stats(t=time.time(), frames=120, ready=True, fps=float(np.float32(29.5)), laser="on",
                                  estimator="s2", drops={"queue": int(np.int64(3))}, ambient_level=float("nan")))
    message = subscriber.wait_for(TOPICS.stats, lambda m: True, "stats")
    assert message.json()["ambient_level"] is None  # NaN is not JSON: null
    stats = Stats.model_validate_json(message.payload)
    assert stats.fps == pytest.approx(29.5) and stats.drops == {"queue": 3, "dropped_queue": 0, "dropped_invalid": 0} \
        and stats.frames == 120
    assert stats.mqtt is not None and stats.mqtt["connected"] is True and stats.mqtt["alerts_pending"] == 0
    assert stats.mqtt["storage_faults"] == 0 and stats.mqtt["storage_error"] is None


# -- commands --------------------------------------------------------------------------------

def test_commands_validated_dispatched_and_answered(broker, subscribers, publishers):
    calls: list[tuple[str, Any]] = []

    def handler(name: str, command: Any) -> dict[str, Any]:
        calls.append((name, command))
        if name == "rebaseline":
            return {"ok": False, "error": "window not full yet"}
        if name == "dark":
            raise RuntimeError("relay jammed")
        return {"laser": "on"}

    replies = subscribers(broker.port, [f"{TOPICS.base}/cmd/+/reply"])
    sender = replies.client
    # A retained command (an operator's slip) would run again on every reconnection: it is
    # refused when the broker replays it to the publisher's new subscription.
    sender.publish(TOPICS.command("laser"), signed(TOPICS.command("laser"), {"state": "on"}), qos=1,
                   retain=True).wait_for_publish(5)
    publisher = publishers(_settings(broker.port), on_command=handler)
    publisher.wait_connected(WAIT_S)
    retained = replies.wait_for(TOPICS.reply("laser"), lambda m: True, "the reply to a retained command").json()
    assert retained["ok"] is False and "retained" in retained["error"]
    sender.publish(TOPICS.command("laser"), b"", qos=1, retain=True).wait_for_publish(5)  # clear it

    def ask(name: str, payload: bytes | str) -> dict[str, Any]:
        before = len(replies.on(TOPICS.reply(name)))
        sender.publish(TOPICS.command(name), payload, qos=1)
        wait_until(lambda: len(replies.on(TOPICS.reply(name))) > before, WAIT_S, f"a reply to {name}")
        return replies.on(TOPICS.reply(name))[-1].json()

    bad_json = ask("laser", "{state: on")
    assert bad_json["ok"] is False and "not valid JSON" in bad_json["error"]
    unknown = ask("explode", json.dumps({"request_id": "r1"}))
    assert unknown["ok"] is False and "unknown command 'explode'" in unknown["error"]
    assert unknown["request_id"] == "r1"
    unsigned = ask("laser", json.dumps({"state": "on", "request_id": 6}))
    assert unsigned["ok"] is False and unsigned["error"].startswith("not signed") and unsigned["request_id"] == 6
    bad_field = ask("laser", signed(TOPICS.command("laser"), {"state": "maybe"}, request_id=7))
    assert bad_field["ok"] is False and bad_field["error"].startswith("state:") and bad_field["request_id"] == 7
    extra = ask("dark", signed(TOPICS.command("dark"), {"frames": 10}))
    assert extra["ok"] is False and "frames: unknown key" in extra["error"]
    not_object = ask("laser", "[1, 2]")
    assert not_object["ok"] is False and "JSON object" in not_object["error"]
    bad_id = ask("laser", json.dumps({"state": "on", "request_id": {"x": 1}}))
    assert bad_id["ok"] is False and "request_id" in bad_id["error"]
    assert calls == []  # nothing invalid reached the handler

    good = ask("laser", signed(TOPICS.command("laser"), {"state": "on"}, request_id="abc"))
    assert good == {**good, "ok": True, "error": None, "request_id": "abc", "command": "laser",
                    "result": {"laser": "on"}}
    assert calls == [("laser", LaserCommand(state="on"))]
    refused = ask("rebaseline", signed(TOPICS.command("rebaseline")))
    assert refused["ok"] is False and refused["error"] == "window not full yet"
    crashed = ask("dark", signed(TOPICS.command("dark")))
    assert crashed["ok"] is False and "relay jammed" in crashed["error"]
    maps = ask("publish_maps", "{}")  # open: changes nothing
    assert maps["ok"] is True and maps["result"] == {"laser": "on"}
    assert [name for name, _ in calls] == ["laser", "rebaseline", "dark", "publish_maps"]
    assert publisher.connected  # the handler's exception did not hurt the connection


def test_mqtt5_correlation_data_is_echoed_on_the_own_reply_topic(broker, subscribers, publishers):
    publisher = publishers(_settings(broker.port), on_command=lambda name, command: {"done": name})
    publisher.wait_connected(WAIT_S)
    requester = subscribers(broker.port, ["ops/replies/7", TOPICS.reply("rebaseline")], protocol=mqtt.MQTTv5)
    properties = Properties(PacketTypes.PUBLISH)
    properties.ResponseTopic = "ops/replies/7"
    properties.CorrelationData = b"req-42"
    requester.client.publish(TOPICS.command("rebaseline"), signed(TOPICS.command("rebaseline")), qos=1,
                             properties=properties)
    reply = requester.wait_for(TOPICS.reply("rebaseline"), lambda m: True, "a reply on the own reply topic")
    assert reply.json()["ok"] is True and reply.json()["result"] == {"done": "rebaseline"}
    assert reply.properties.CorrelationData == b"req-42"
    time.sleep(0.3)
    assert requester.on("ops/replies/7") == []  # the requester's response topic is not published to


def test_without_handler_daemon_commands_are_refused(broker, subscribers, publishers):
    replies = subscribers(broker.port, [f"{TOPICS.base}/cmd/+/reply"])
    publisher = publishers(_settings(broker.port))
    publisher.wait_connected(WAIT_S)
    replies.client.publish(TOPICS.command("dark"), signed(TOPICS.command("dark")), qos=1)
    reply = replies.wait_for(TOPICS.reply("dark"), lambda m: True, "reply").json()
    assert reply["ok"] is False and "no handler" in reply["error"]


# -- TLS and passwords -----------------------------------------------------------------------

@pytest.fixture
def secure_broker(make_broker: Callable[..., Broker], tmp_path: Path) -> tuple[Broker, TlsFiles]:
    tls = make_certificates(tmp_path / "pki")
    passwords = tmp_path / "passwd"
    result = subprocess.run([tool("mosquitto_passwd", "mosquitto"), "-b", "-c", str(passwords), "line3", "s3cret"],
                            capture_output=True, text=True, timeout=30)
    if result.returncode != 0:
        pytest.fail(f"mosquitto_passwd failed:\n{result.stderr}")
    return make_broker(tls=tls, password_file=passwords), tls


def _tls_settings(broker: Broker, tls: TlsFiles, **kwargs: Any) -> MqttSettings:
    return _settings(broker.port, host="localhost", username="line3",
                     tls={"ca_file": tls.ca, "cert_file": tls.client_cert, "key_file": tls.client_key}, **kwargs)


def test_tls_with_client_certificate_and_password(secure_broker, subscribers, publishers, monkeypatch):
    broker, tls = secure_broker
    monkeypatch.setenv("EDGEDSM_MQTT_PASSWORD", "s3cret")  # the way the daemon gets it
    publisher = publishers(_tls_settings(broker, tls))
    publisher.wait_connected(WAIT_S)
    publisher.publish_state(_state(A="dry"))
    seq = publisher.publish_alert(_alert("transition", region="A", from_state="drying", to_state="dry"))
    subscriber = subscribers(broker.port, [TOPICS.state, TOPICS.alerts], tls=tls, username="line3",
                             password="s3cret")
    subscriber.wait_for(TOPICS.state, lambda m: _region_state(m, "A") == "dry", "state over TLS")
    assert publisher.flush_alerts(WAIT_S)
    assert publisher.counters()["alerts_acked"] == 1 and seq == 1


def test_wrong_password_is_a_clear_error(secure_broker, publishers):
    broker, tls = secure_broker
    # refused at the first connection: these credentials can never work, a configuration error (exit 78)
    with pytest.raises(ConfigError, match=r"^mqtt.username: broker localhost:\d+ refused the connection: "
                                          r"(Bad user name or password|Not authorized)") as error:
        publishers(_tls_settings(broker, tls), password="wrong")
    assert "user 'line3'" in str(error.value) and "wrong" not in str(error.value)
    assert error.value.exit_code == 78


# paho 2.2 does not close the socket of a failed TLS handshake (the GC does); not our leak.
@pytest.mark.filterwarnings("ignore::pytest.PytestUnraisableExceptionWarning")
def test_untrusted_broker_certificate_is_a_clear_error(secure_broker, publishers, tmp_path):
    broker, tls = secure_broker
    other = make_certificates(tmp_path / "other-pki")  # a CA that did not sign the broker
    settings = _settings(broker.port, host="localhost", username="line3",
                         tls={"ca_file": other.ca, "cert_file": tls.client_cert, "key_file": tls.client_key})
    publisher = publishers(settings, password="s3cret")
    with pytest.raises(PublishError, match=r"certificate .* was not accepted"):
        publisher.wait_connected(1.5)
    publisher.close(1.5)
    gc.collect()  # let paho's leaked sockets be reported inside this test (see the mark)


# -- edgedsm watch ---------------------------------------------------------------------------

def _watch(*args: str, env: dict[str, str] | None = None) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "edgedsm", "watch", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env={**child_env(), **(env or {})})


def _lines_until(process: subprocess.Popen[str], needle: str, lines: list[str], timeout: float = WAIT_S) -> None:
    """Read the watcher's output until a line contains ``needle`` (bounded by a reader thread)."""
    done = threading.Event()

    def read() -> None:
        assert process.stdout is not None
        for line in process.stdout:
            lines.append(line.rstrip("\n"))
            if needle in line:
                done.set()
                return
        done.set()

    threading.Thread(target=read, daemon=True).start()
    if not done.wait(timeout) or not any(needle in line for line in lines):
        process.kill()
        _, err = process.communicate(timeout=10)
        pytest.fail(f"watch never printed {needle!r}; it printed {lines!r}; stderr:\n{err}")


@pytest.mark.slow  # starts `python -m edgedsm` (seconds of imports)
def test_watch_prints_availability_states_and_alerts_once(broker, publishers, tmp_path):
    publisher = publishers(_settings(broker.port))
    publisher.wait_connected(WAIT_S)
    panel = RegionState(region="panel", state="wet", since=1.0, activity=0.41)
    publisher.publish_state(StateReport(t=1.0, estimator="s2", regions={"panel": panel}))
    maps_dir = tmp_path / "maps"
    watch = _watch("--port", str(broker.port), "--host", "127.0.0.1", "--device", "cam0", "--count", "2",
                   "--timeout", "30", "--save-maps", str(maps_dir))
    lines: list[str] = []
    try:
        _lines_until(watch, "panel: wet", lines)  # retained state seen: the subscription is active
        drying = panel.model_copy(update={"state": "drying", "since": 2.0, "activity": 0.22})
        publisher.publish_state(StateReport(t=2.0, estimator="s2", regions={"panel": drying}))
        alert = _alert("transition", region="panel", from_state="wet", to_state="drying", activity=0.22)
        publisher.publish_alert(alert)
        assert publisher.flush_alerts(WAIT_S)
        # a resend of alert 1, as after a reconnection: must not be printed again
        resend = alert.model_copy(update={"seq": 1, "stream": publisher.alert_stream})
        _publish_raw(broker.port, TOPICS.alerts, resend.to_bytes().decode())
        publisher.publish_map(MapFrame("s1", np.outer(np.arange(20.0), np.ones(30)), seq=77, t=time.time(),
                                       window=200, lag=10))
        _lines_until(watch, "map s1", lines)
        publisher.publish_alert(alert.model_copy(update={"from_state": "drying", "to_state": "dry",
                                                         "activity": 0.05}))
        out, err = watch.communicate(timeout=WAIT_S)
    finally:
        if watch.poll() is None:
            watch.kill()
            watch.communicate(timeout=10)
    lines += out.splitlines()
    text = "\n".join(lines)
    assert watch.returncode == 0, err
    assert any(line.endswith("availability  online (retained)") for line in lines), text
    assert any("state         panel: wet (activity 0.41)" in line for line in lines), text
    assert any("state         panel: wet -> drying (activity 0.22)" in line for line in lines), text
    alert_lines = [line for line in lines if "  alert #" in line]
    assert len(alert_lines) == 2, text  # the resend was deduplicated
    assert "alert #1      panel: wet -> drying (activity 0.22) [transition]" in alert_lines[0]
    assert "alert #2      panel: drying -> dry" in alert_lines[1]
    assert (maps_dir / "s1-0000000077.png").stat().st_size > 1000
    stamp = lines[0][:23]
    assert time.strptime(stamp[:19], "%Y-%m-%d %H:%M:%S")  # every line starts with a timestamp


def _publish_raw(port: int, topic: str, payload: str) -> None:
    client = mqtt.Client(CallbackAPIVersion.VERSION2)
    client.connect("127.0.0.1", port)
    client.loop_start()
    try:
        client.publish(topic, payload, qos=1).wait_for_publish(5)
    finally:
        client.disconnect()
        client.loop_stop()


@pytest.mark.slow  # starts `python -m edgedsm` (seconds of imports)
def test_watch_timeout_and_count_not_reached(broker):
    started = time.monotonic()
    quiet = _watch("--port", str(broker.port), "--host", "127.0.0.1", "--timeout", "1")
    out, err = quiet.communicate(timeout=WAIT_S)
    assert quiet.returncode == 0, err
    assert "watching edgedsm/camera1" in out
    short = _watch("--port", str(broker.port), "--host", "127.0.0.1", "--count", "1", "--timeout", "1")
    out, err = short.communicate(timeout=WAIT_S)
    assert short.returncode == 1 and "timed out after 1 s with 0 of 1 alert(s)" in err
    assert time.monotonic() - started < 20


@pytest.mark.slow  # starts `python -m edgedsm` (seconds of imports)
def test_watch_over_tls_with_password_from_environment(secure_broker, publishers, monkeypatch):
    broker, tls = secure_broker
    monkeypatch.setenv("EDGEDSM_MQTT_PASSWORD", "s3cret")
    publisher = publishers(_tls_settings(broker, tls))
    publisher.wait_connected(WAIT_S)
    common = ["--host", "localhost", "--port", str(broker.port), "--device", "cam0", "--username", "line3",
              "--ca-file", str(tls.ca),
              "--cert-file", str(tls.client_cert), "--key-file", str(tls.client_key), "--timeout", "2"]
    good = _watch(*common, env={"EDGEDSM_MQTT_PASSWORD": "s3cret"})
    out, err = good.communicate(timeout=WAIT_S)
    assert good.returncode == 0, err
    assert "availability  online" in out
    bad = _watch(*common, env={"EDGEDSM_MQTT_PASSWORD": "nope"})
    out, err = bad.communicate(timeout=WAIT_S)
    assert bad.returncode == 1
    assert "refused the connection" in err and "user 'line3'" in err


def test_deeply_nested_or_huge_command_is_refused_with_a_reply(broker, subscribers, publishers):
    calls: list[str] = []
    publisher = publishers(_settings(broker.port), on_command=lambda name, command: calls.append(name))
    publisher.wait_connected(WAIT_S)
    replies = subscribers(broker.port, [f"{TOPICS.base}/cmd/+/reply"])
    # the payload: 100 000 deep (RecursionError in the parser, no reply)
    replies.client.publish(TOPICS.command("laser"), b"[" * 100_000 + b"]" * 100_000, qos=1)
    huge = replies.wait_for(TOPICS.reply("laser"), lambda m: True, "a reply to a huge command").json()
    assert huge["ok"] is False and "200000 bytes exceeds the 16384-byte limit" in huge["error"]
    # deep within the size bound; brackets inside strings do not count
    deep_payload = '{"request_id": "[[[[[[[[[[[[", "x": ' + "[" * 5000 + "]" * 5000 + "}"
    replies.client.publish(TOPICS.command("dark"), deep_payload, qos=1)
    deep = replies.wait_for(TOPICS.reply("dark"), lambda m: True, "a reply to a deeply nested command").json()
    assert deep["ok"] is False and "nested deeper than 8 levels" in deep["error"]
    # a modest nesting is parsed and refused on its merits
    replies.client.publish(TOPICS.command("rebaseline"), signed(TOPICS.command("rebaseline"), {"a": [[{"b": [1]}]]}),
                           qos=1)
    merits = replies.wait_for(TOPICS.reply("rebaseline"), lambda m: True, "a reply to rebaseline").json()
    assert merits["ok"] is False and "a: unknown key" in merits["error"]
    assert calls == [] and publisher.connected


@pytest.mark.parametrize("response_topic", [TOPICS.alerts, "edgedsm/other/cmd/laser", "homeassistant/switch/x/config",
                                            "spBv1.0/plant/DCMD/edge/cam0", "ops/replies/7"])
def test_a_response_topic_is_never_published_to(broker, subscribers, publishers, response_topic):
    calls: list[str] = []
    publisher = publishers(_settings(broker.port), on_command=lambda name, command: calls.append(name))
    publisher.wait_connected(WAIT_S)
    watcher = subscribers(broker.port, ["#"], protocol=mqtt.MQTTv5)
    properties = Properties(PacketTypes.PUBLISH)
    properties.ResponseTopic = response_topic
    properties.CorrelationData = b"c-1"
    watcher.client.publish(TOPICS.command("dark"), signed(TOPICS.command("dark"), request_id=5), qos=1,
                           properties=properties)
    reply = watcher.wait_for(TOPICS.reply("dark"), lambda m: True, "the reply on the own reply topic")
    assert reply.json()["ok"] is True and reply.json()["request_id"] == 5
    assert reply.properties.CorrelationData == b"c-1"
    time.sleep(0.3)  # nothing may have been published on the requested topic
    assert [m for m in watcher.messages if m.topic == response_topic] == []
    assert calls == ["dark"]


def test_response_topic_own_reply_topic_is_accepted(broker, subscribers, publishers):
    publisher = publishers(_settings(broker.port), on_command=lambda name, command: {"done": name})
    publisher.wait_connected(WAIT_S)
    requester = subscribers(broker.port, [TOPICS.reply("dark")], protocol=mqtt.MQTTv5)
    properties = Properties(PacketTypes.PUBLISH)
    properties.ResponseTopic = TOPICS.reply("dark")
    requester.client.publish(TOPICS.command("dark"), signed(TOPICS.command("dark")), qos=1, properties=properties)
    reply = requester.wait_for(TOPICS.reply("dark"), lambda m: True, "a reply on the own reply topic")
    assert reply.json() == {**reply.json(), "ok": True, "result": {"done": "dark"}}
