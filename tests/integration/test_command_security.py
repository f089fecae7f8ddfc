"""Commands are authorised, with real parts: mosquitto run with the shipped config/mosquitto files
(edgedsm.conf with its paths and port templated, the acl file as shipped) over TLS with passwords,
the daemon as a process reading its command key and password from systemd-style credentials, a
Numato relay board emulated on a socat PTY (every byte it receives is kept), and `edgedsm cmd`.

Nobody without a command key switches the laser: an anonymous client cannot connect, the viewer
and dashboard users cannot publish to cmd/laser (ACL), and the operator user's unsigned, expired,
replayed, retained, foreign-device and wrongly-keyed commands are refused with a reply, while the
relay receives not one byte more. A signed `edgedsm cmd` is obeyed. No MQTT 5 Response Topic is
published to. The dashboard signs its commands.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
import pytest
from helpers_commands import NO_KEY_ENV, signed
from helpers_daemon import Daemon, base_config, write_config
from helpers_mqtt import REPO, WAIT_S, Broker, Subscriber, TlsFiles, child_env, make_certificates, tool, wait_until
from helpers_relay import NumatoBoard, open_pty_pair
from paho.mqtt.enums import CallbackAPIVersion
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties

from edgedsm.dashboard.subscriber import PlantSubscriber
from edgedsm.publish import MqttSettings, Topics

pytestmark = [pytest.mark.integration, pytest.mark.slow]

SHIPPED = REPO / "config" / "mosquitto"
TOPICS = Topics.of("edgedsm", "line3")  # the device the shipped acl names
CHANNEL = 3
PASSWORDS = {"edgedsm-line3": "daemon-pw", "edgedsm-operator": "operator-pw", "edgedsm-viewer": "viewer-pw",
             "edgedsm-dashboard": "dashboard-pw"}
ALICE = "a1" * 32          # the operator's key
DASHBOARD = "d4" * 32      # the dashboard's key
MALLORY = "m0" * 32        # a key the daemon does not hold
BY_ALICE = {"key_id": "alice", "secret": ALICE}


@pytest.fixture
def plant_broker(tmp_path: Path) -> Iterator[tuple[Broker, TlsFiles]]:
    """mosquitto with the shipped edgedsm.conf and acl, its certificates and password file."""
    tls = make_certificates(tmp_path / "pki")
    etc = tmp_path / "etc-mosquitto"
    etc.mkdir()
    for name in ("ca.crt", "server.crt", "server.key"):
        shutil.copy(tls.ca.parent / name, etc / name)
    shutil.copy(SHIPPED / "acl", etc / "acl")
    passwd = tool("mosquitto_passwd", "mosquitto")
    for i, (user, password) in enumerate(PASSWORDS.items()):
        subprocess.run([passwd, "-b", *(["-c"] if i == 0 else []), str(etc / "passwd"), user, password],
                       check=True, capture_output=True, timeout=30)
    shipped = (SHIPPED / "edgedsm.conf").read_text()
    settings_lines = [line for line in shipped.splitlines() if line and not line.startswith("#")]
    assert "listener 8883" in settings_lines
    assert sum("/etc/mosquitto/edgedsm/" in line for line in settings_lines) == 5  # passwd acl ca cert key

    def settings(port: int) -> str:
        return "\n".join(settings_lines).replace("listener 8883", f"listener {port} 127.0.0.1") \
            .replace("/etc/mosquitto/edgedsm/", f"{etc}/")

    broker = Broker(tmp_path / "broker", settings=settings).start()
    yield broker, tls
    broker.stop()


def client(broker: Broker, tls: TlsFiles, user: str | None, topics: list[str], **kwargs: Any) -> Subscriber:
    made = Subscriber(broker.port, topics, tls=tls, username=user, password=PASSWORDS.get(user or ""), **kwargs)
    return made.start()


def edgedsm_cmd(broker: Broker, tls: TlsFiles, name: str, args: dict[str, Any], *, key_file: Path | None,
                env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    options = ["--broker", f"localhost:{broker.port}", "--device", "line3", "--username", "edgedsm-operator",
               "--ca-file", str(tls.ca), "--args", json.dumps(args), "--timeout", "5"]
    if key_file is not None:
        options += ["--command-key-file", str(key_file)]
    return subprocess.run([sys.executable, "-m", "edgedsm", "cmd", name, *options], capture_output=True, text=True,
                          env={**child_env(), "EDGEDSM_MQTT_PASSWORD": PASSWORDS["edgedsm-operator"],
                               **(env or {})}, timeout=WAIT_S + 20)


def relay_ons(board: NumatoBoard, since: int) -> list[bytes]:
    return [frame for frame in board.frames()[since:] if frame.startswith(b"relay on")]


@pytest.mark.timeout(150)
def test_only_signed_commands_switch_the_laser(tmp_path: Path, plant_broker: tuple[Broker, TlsFiles],
                                               daemons: Callable[..., Daemon]) -> None:
    broker, tls = plant_broker
    credentials = tmp_path / "credentials"  # what systemd's LoadCredential= gives the daemon
    credentials.mkdir()
    (credentials / "mqtt-password").write_text(PASSWORDS["edgedsm-line3"] + "\n")
    (credentials / "command-key").write_text(f"# operators\nalice {ALICE}\ndashboard {DASHBOARD}\n")
    alice_key = tmp_path / "alice.key"
    alice_key.write_text(f"alice {ALICE}\n")
    mallory_key = tmp_path / "mallory.key"
    mallory_key.write_text(f"alice {MALLORY}\n")  # alice's id, the wrong secret

    with open_pty_pair(tmp_path) as pair:
        board = NumatoBoard(pair.board, CHANNEL)
        board.start()
        config = base_config(tmp_path, device="line3", port=broker.port,
                             laser=f"serial:{pair.app}?protocol=numato&channel={CHANNEL}&timeout=0.3")
        config["mqtt"].update(host="localhost", username="edgedsm-line3")
        config["mqtt.tls"] = {"ca_file": tls.ca}
        daemon = daemons(write_config(tmp_path / "daemon.toml", config),
                         {"CREDENTIALS_DIRECTORY": str(credentials), **NO_KEY_ENV})
        # reads everything under edgedsm/ (the shipped acl's viewer), commands included
        watcher = client(broker, tls, "edgedsm-viewer", ["edgedsm/#"])
        operator = client(broker, tls, "edgedsm-operator", [f"{TOPICS.base}/cmd/+/reply"])
        try:
            daemon.wait_until(lambda: board.is_on, 40, "measuring with the laser on")
            wait_until(lambda: bool(watcher.on(TOPICS.stats)), WAIT_S, "stats through the viewer")

            # -- an authorised operator: edgedsm cmd signs with alice's key; obeyed
            on = edgedsm_cmd(broker, tls, "laser", {"state": "on"}, key_file=alice_key)
            assert on.returncode == 0, on.stderr
            captured = watcher.wait_for(TOPICS.command("laser"), lambda m: True, "the signed laser on").payload
            assert json.loads(captured)["key_id"] == "alice"  # the viewer saw it go by
            off = edgedsm_cmd(broker, tls, "laser", {"state": "off"}, key_file=alice_key)
            assert off.returncode == 0, off.stderr
            assert "laser accepted" in off.stdout
            daemon.wait_until(lambda: not board.is_on, WAIT_S, "the laser off")
            assert board.frames()[-2:] == [b"relay off 3\r", b"relay read 3\r"]
            mark, marked_at = len(board.frames()), time.monotonic()

            # -- everyone else
            anonymous = mqtt.Client(CallbackAPIVersion.VERSION2)
            anonymous.tls_set(ca_certs=str(tls.ca))
            refused: list[Any] = []
            anonymous.on_connect = lambda c, u, f, reason, p: refused.append(reason)
            anonymous.connect("localhost", broker.port)
            anonymous.loop_start()
            wait_until(lambda: bool(refused), WAIT_S, "the broker's answer to an anonymous client")
            anonymous.loop_stop()
            assert refused[0].is_failure and "authori" in str(refused[0]).lower()

            dropped = {}
            for user in ("edgedsm-viewer", "edgedsm-dashboard"):  # the acl: no write to cmd/laser
                other = client(broker, tls, user, [f"{TOPICS.base}/nothing"])
                dropped[user] = f"acl-{user}"
                other.client.publish(TOPICS.command("laser"), signed(TOPICS.command("laser"), {"state": "on"},
                                                                     request_id=dropped[user]), qos=1)
                other.stop()

            def ask(payload: str, request_id: str) -> dict[str, Any]:
                operator.client.publish(TOPICS.command("laser"), payload, qos=1)
                return operator.wait_for(TOPICS.reply("laser"), lambda m: m.json()["request_id"] == request_id,
                                         f"the reply to {request_id}").json()

            laser_on = TOPICS.command("laser")
            attempts = {  # request_id: (payload, what the refusal says)
                "unsigned": (json.dumps({"state": "on", "request_id": "unsigned"}), "not signed"),
                "replayed": (json.dumps({**json.loads(captured), "request_id": "replayed"}), "replayed"),
                "expired": (signed(laser_on, {"state": "on"}, request_id="expired", now=time.time() - 120,
                                   **BY_ALICE), "expired: issued 12"),
                "line4": (signed(Topics.of("edgedsm", "line4").command("laser"), {"state": "on"},
                                 request_id="line4", **BY_ALICE), "bad signature"),
                "mallory": (signed(laser_on, {"state": "on"}, request_id="mallory", key_id="mallory"),
                            "unknown key id 'mallory'"),
                "wrong-secret": (signed(laser_on, {"state": "on"}, request_id="wrong-secret", key_id="alice",
                                        secret=MALLORY), "bad signature"),
                "altered": (json.dumps({**json.loads(captured), "state": "on", "request_id": "altered",
                                        "nonce": uuid.uuid4().hex}), "bad signature"),
            }
            for request_id, (payload, why) in attempts.items():
                reply = ask(payload, request_id)
                assert reply["ok"] is False and why in reply["error"], (request_id, reply)
            # retained, signed and fresh: refused on its first (live) delivery, MQTT 5 retain-as-published
            operator.client.publish(laser_on, signed(laser_on, {"state": "on"}, request_id="retained", **BY_ALICE),
                                    qos=1, retain=True)
            # refused before it is parsed, so without its request_id
            reply = operator.wait_for(TOPICS.reply("laser"), lambda m: "retained" in (m.json()["error"] or ""),
                                      "the refusal of a retained command").json()
            assert reply["ok"] is False and reply["error"].startswith("retained commands are refused"), reply
            operator.client.publish(laser_on, b"", qos=1, retain=True).wait_for_publish(5)
            # edgedsm cmd without a key, and with a wrong one
            nokey = edgedsm_cmd(broker, tls, "laser", {"state": "on"}, key_file=None, env=NO_KEY_ENV)
            assert nokey.returncode == 1 and "refused laser: not signed" in nokey.stderr, nokey.stderr
            wrong = edgedsm_cmd(broker, tls, "laser", {"state": "on"}, key_file=mallory_key)
            assert wrong.returncode == 1 and "bad signature" in wrong.stderr, wrong.stderr

            time.sleep(1.0)  # an ACL-dropped command would have been answered by now
            answered = {m.json()["request_id"] for m in operator.on(TOPICS.reply("laser"))}
            assert not set(dropped.values()) & answered
            print(f"{len(attempts) + 5} unauthorised laser-on attempts in {time.monotonic() - marked_at:.1f} s: "
                  f"relay frames {board.frames()[mark:]}")
            assert relay_ons(board, mark) == [] and not board.is_on
            assert board.frames()[mark:] == []  # not one byte to the relay
            assert daemon.process.poll() is None

            # -- no Response Topic is published to, even inside the daemon's own topics
            requester = client(broker, tls, "edgedsm-operator", [f"{TOPICS.base}/cmd/#"], protocol=mqtt.MQTTv5)
            for i, response_topic in enumerate([TOPICS.command("laser"), TOPICS.command("dark")]):
                properties = Properties(PacketTypes.PUBLISH)
                properties.ResponseTopic = response_topic
                properties.CorrelationData = f"c{i}".encode()
                requester.client.publish(TOPICS.command("publish_maps"), json.dumps({"request_id": f"rt{i}"}),
                                         qos=1, properties=properties)
                reply = requester.wait_for(TOPICS.reply("publish_maps"), lambda m: m.json()["request_id"] == f"rt{i}",  # noqa: B023
                                           "the reply on the own reply topic")
                assert reply.json()["ok"] is True and reply.properties.CorrelationData == f"c{i}".encode()
            time.sleep(0.5)
            assert requester.on(TOPICS.command("dark")) == [] and \
                [m for m in requester.on(TOPICS.command("laser")) if b"rt" in m.payload] == []
            requester.stop()

            # -- the dashboard signs with its own key (the dashboard user may send dark, never laser)
            settings = MqttSettings(host="localhost", port=broker.port, username="edgedsm-dashboard",
                                    tls={"ca_file": tls.ca})
            seen: list[str] = []
            plant = type("Plant", (), {"handle": lambda self, topic, payload: seen.append(topic)})()
            dashboard = PlantSubscriber(settings, plant, password=PASSWORDS["edgedsm-dashboard"],
                                        command_keys={"dashboard": DASHBOARD.encode()})
            dashboard.start()
            try:
                wait_until(dashboard.connected.is_set, WAIT_S, "the dashboard connected")
                dashboard.send_command("line3", "dark")
                reply = operator.wait_for(TOPICS.reply("dark"), lambda m: True, "the reply to the dashboard's dark")
                assert reply.json()["ok"] is True, reply.json()
                with pytest.raises(ValueError, match="not allowed from the dashboard"):
                    dashboard.send_command("line3", "laser")
            finally:
                dashboard.stop()
            daemon.wait_log(r"MQTT command 'dark' signed by key 'dashboard' accepted", WAIT_S)
            assert not board.is_on  # dark frames keep it off; it is still held off
        finally:
            operator.stop()
            watcher.stop()
            code, _ = daemon.terminate()
            board.stop()
    assert code == 0, daemon.log
    assert not board.is_on and board.errors == []
    assert "Traceback" not in daemon.log


def test_a_daemon_without_a_key_is_read_only(tmp_path: Path, plant_broker: tuple[Broker, TlsFiles],
                                             daemons: Callable[..., Daemon]) -> None:
    broker, tls = plant_broker
    credentials = tmp_path / "credentials"
    credentials.mkdir()
    (credentials / "mqtt-password").write_text(PASSWORDS["edgedsm-line3"])
    config = base_config(tmp_path, device="line3", port=broker.port)
    config["mqtt"].update(host="localhost", username="edgedsm-line3")
    config["mqtt.tls"] = {"ca_file": tls.ca}
    daemon = daemons(write_config(tmp_path / "daemon.toml", config),
                     {"CREDENTIALS_DIRECTORY": str(credentials), **NO_KEY_ENV})
    operator = client(broker, tls, "edgedsm-operator", [f"{TOPICS.base}/cmd/+/reply", TOPICS.availability])
    try:
        daemon.wait_log(r"no command key .*read-only", 30)
        operator.wait_for(TOPICS.availability, lambda m: m.payload == b"online", "online", timeout=30)
        replies: dict[str, dict[str, Any]] = {}
        for name, args in [("laser", {"state": "on"}), ("rebaseline", {}), ("dark", {}), ("record", {}),
                           ("publish_maps", {})]:
            request_id = f"ro-{name}"
            operator.client.publish(TOPICS.command(name), signed(TOPICS.command(name), args, request_id=request_id),
                                    qos=1)
            replies[name] = operator.wait_for(TOPICS.reply(name), lambda m: m.json()["request_id"] == request_id,  # noqa: B023
                                              f"the reply to {name}").json()
        assert {name: reply["ok"] for name, reply in replies.items()} == {
            "laser": False, "rebaseline": False, "dark": False, "record": False, "publish_maps": True}
        assert all(replies[name]["error"].startswith("read-only: no command key")
                   for name in ("laser", "rebaseline", "dark", "record"))
    finally:
        operator.stop()
        code, _ = daemon.terminate()
    assert code == 0, daemon.log


# the mosquitto users of the shipped acl, one by one (no daemon needed)
@pytest.mark.parametrize(("user", "topic", "may_write"), [
    ("edgedsm-line3", "edgedsm/line3/state", True),
    ("edgedsm-line3", "edgedsm/line4/state", False),        # not another device's topics
    ("edgedsm-dashboard", "edgedsm/line3/cmd/dark", True),
    ("edgedsm-dashboard", "edgedsm/line3/cmd/laser", False),
    ("edgedsm-viewer", "edgedsm/line3/cmd/publish_maps", False),
    ("edgedsm-operator", "edgedsm/line3/cmd/laser", True),
    ("edgedsm-operator", "edgedsm/line3/state", False),
])
def test_the_shipped_acl(plant_broker: tuple[Broker, TlsFiles], user: str, topic: str, may_write: bool) -> None:
    broker, tls = plant_broker
    watcher = client(broker, tls, "edgedsm-viewer", ["edgedsm/#"])
    writer = client(broker, tls, user, [f"{TOPICS.base}/nothing"])
    try:
        writer.client.publish(topic, b"probe", qos=1).wait_for_publish(5)
        time.sleep(0.5)
        assert bool([m for m in watcher.on(topic) if m.payload == b"probe"]) is may_write
    finally:
        writer.stop()
        watcher.stop()
