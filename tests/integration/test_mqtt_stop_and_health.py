"""What a stopped daemon leaves on the broker, and what `/healthz` says of the MQTT link: a real
daemon (`edgedsm run`, simulated camera and relay) against a REAL mosquitto.

- SIGTERM: the retained state a subscriber arriving afterwards reads says ``offline``, the laser
  ``off`` and no time to dry (it said ``on`` and a time to dry while measuring); the Sparkplug
  node's last DDATA says the same before its NDEATH.
- A password the broker refuses at the first connection can never work: exit 78 within seconds,
  the key path in the log.
- The broker starts refusing the daemon's password while it runs (its password file changed):
  `/healthz` answers 503 naming the refusal, though frames still flow; 200 again once accepted.
"""

from __future__ import annotations

import http.client
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from helpers_daemon import Daemon, base_config, wait_frames_beyond, write_config
from helpers_mqtt import WAIT_S, Broker, Subscriber, free_port, tool, wait_until

from edgedsm.publish import Topics
from tests.sparkplug_decoder import decode

pytestmark = [pytest.mark.integration, pytest.mark.slow]

TOPICS = Topics.of("edgedsm", "e2e")


def _passwords(path: Path, password: str) -> Path:
    result = subprocess.run([tool("mosquitto_passwd", "mosquitto"), "-b", "-c", str(path), "line3", password],
                            capture_output=True, text=True, timeout=30)
    if result.returncode != 0:
        pytest.fail(f"mosquitto_passwd failed:\n{result.stderr}")
    return path


def _healthz(port: int) -> tuple[int, str]:
    """(status, body) of ``/healthz``; (0, why) while nothing listens yet."""
    connection = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
    try:
        connection.request("GET", "/healthz")
        response = connection.getresponse()
        return response.status, response.read().decode()
    except OSError as exc:
        return 0, str(exc)
    finally:
        connection.close()


@pytest.mark.timeout(90)
def test_sigterm_leaves_a_retained_state_that_says_offline_and_laser_off(
        tmp_path: Path, broker: Broker, subscribers: Callable[..., Subscriber], daemons: Callable[..., Daemon],
        sim_board_name: str) -> None:
    live = subscribers(broker.port, [TOPICS.state, TOPICS.stats, TOPICS.availability, "spBv1.0/#"])
    config = base_config(tmp_path, port=broker.port, laser=f"sim:{sim_board_name}")
    config["sparkplug"] = {"group_id": "line3"}
    daemon = daemons(write_config(tmp_path / "daemon.toml", config))
    wait_frames_beyond(live, TOPICS, 120, timeout=30)
    wait_until(lambda: any(m.json()["laser"] == "on" for m in live.on(TOPICS.state)), WAIT_S,
               "a state saying the laser is on")
    measuring = [m.json() for m in live.on(TOPICS.state)]
    assert all(state["availability"] == "online" for state in measuring)
    code, took = daemon.terminate()
    assert code == 0 and took < 2.0, daemon.log
    # a subscriber arriving after the stop reads only what is retained
    late = subscribers(broker.port, [TOPICS.state, f"{TOPICS.state}/+", TOPICS.availability])
    wait_until(lambda: late.on(TOPICS.state) and late.on(TOPICS.availability), WAIT_S, "the retained state")
    assert late.on(TOPICS.availability)[-1].payload == b"offline"
    final = late.on(TOPICS.state)[-1]
    assert final.retain
    state = final.json()
    assert state["availability"] == "offline" and state["laser"] == "off"
    assert set(state["regions"]) == {"plate"} and state["regions"]["plate"]["time_to_dry_s"] is None
    assert state["t"] >= measuring[-1]["t"]
    region = late.on(f"{TOPICS.state}/plate")[-1].json()
    assert region["time_to_dry_s"] is None and region["state"] == state["regions"]["plate"]["state"]
    # Sparkplug: a last DDATA says the laser is off and no time to dry, then the NDEATH
    wait_until(lambda: any("/NDEATH/" in m.topic for m in live.messages), WAIT_S, "the NDEATH")
    spb = [m for m in live.messages if m.topic.startswith("spBv1.0/")]
    names = {metric.alias: metric.name for m in spb if "/DBIRTH/" in m.topic for metric in decode(m.payload).metrics}
    last: dict[str, object] = {}
    for message in spb:
        if "/DBIRTH/" in message.topic or "/DDATA/" in message.topic:
            for metric in decode(message.payload).metrics:
                last[metric.name or names[metric.alias]] = metric.value()
    assert last["laser"] == "off" and last["regions/plate/time_to_dry_s"] is None, last
    death = max(i for i, m in enumerate(spb) if "/NDEATH/" in m.topic)
    assert max(i for i, m in enumerate(spb) if "/DDATA/" in m.topic) < death


@pytest.mark.timeout(60)
def test_credentials_refused_at_the_first_connection_exit_78(
        tmp_path: Path, make_broker: Callable[..., Broker], daemons: Callable[..., Daemon]) -> None:
    broker = make_broker(password_file=_passwords(tmp_path / "passwd", "s3cret"))
    config = base_config(tmp_path, port=broker.port)
    config["mqtt"]["username"] = "line3"
    daemon = daemons(write_config(tmp_path / "daemon.toml", config), env={"EDGEDSM_MQTT_PASSWORD": "wrong"})
    started = time.monotonic()
    code = daemon.wait(30)
    assert code == 78, daemon.log
    assert time.monotonic() - started < 20
    assert "mqtt.username" in daemon.log and "refused the connection" in daemon.log
    assert "wrong" not in daemon.log  # the password itself is never logged


@pytest.mark.timeout(120)
def test_healthz_is_503_while_the_broker_refuses_the_password_and_200_again_once_accepted(
        tmp_path: Path, make_broker: Callable[..., Broker], subscribers: Callable[..., Subscriber],
        daemons: Callable[..., Daemon]) -> None:
    passwords = _passwords(tmp_path / "passwd", "s3cret")
    broker = make_broker(password_file=passwords)
    http_port = free_port()
    config = base_config(tmp_path, port=broker.port)
    config["mqtt"]["username"] = "line3"
    config["http"] = {"listen": f"127.0.0.1:{http_port}", "stale_after_s": 3.0}
    daemon = daemons(write_config(tmp_path / "daemon.toml", config), env={"EDGEDSM_MQTT_PASSWORD": "s3cret"})
    daemon.wait_until(lambda: _healthz(http_port)[0] == 200, 30, "/healthz 200")
    assert _healthz(http_port)[1].endswith("; MQTT connected\n")
    _passwords(passwords, "changed")  # the broker's administrator changed the daemon's password
    broker.restart()
    daemon.wait_until(lambda: _healthz(http_port)[0] == 503, 30, "/healthz 503 once the password is refused")
    status, body = _healthz(http_port)
    assert status == 503 and body.startswith("MQTT: broker 127.0.0.1") and "user 'line3'" in body, body
    _passwords(passwords, "s3cret")
    broker.restart()
    daemon.wait_until(lambda: _healthz(http_port)[0] == 200, 30, "/healthz 200 once accepted again")
    assert daemon.process.poll() is None  # a refusal after the first connection is not a reason to exit
