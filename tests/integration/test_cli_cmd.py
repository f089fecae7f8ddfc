"""`edgedsm cmd` against a real daemon on a real mosquitto: exit 0 accepted, 1 refused, 2 no reply (at
once when the daemon is offline), 69 broker unreachable, 78 broker refused the credentials."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from helpers_daemon import Daemon, base_config, write_config
from helpers_mqtt import WAIT_S, Broker, child_env, free_port, tool, wait_until

pytestmark = [pytest.mark.integration, pytest.mark.slow]


@pytest.fixture
def daemon(tmp_path: Path, broker: Broker) -> Iterator[Daemon]:
    config = write_config(tmp_path / "edgedsm.toml", base_config(tmp_path, port=broker.port, device="line3"))
    started = Daemon(config)
    yield started
    started.kill()


def _cmd(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "edgedsm", "cmd", *args], capture_output=True, text=True,
                          env=child_env(), timeout=WAIT_S + 20)


@pytest.mark.timeout(120)
def test_cmd_exit_status_says_accepted_refused_or_no_reply(tmp_path: Path, broker: Broker, daemon: Daemon) -> None:
    broker_arg = f"127.0.0.1:{broker.port}"
    accepted: list[subprocess.CompletedProcess[str]] = []

    def ready() -> bool:  # the daemon answers once its command channel is subscribed
        accepted[:] = [_cmd("publish_maps", "--device", "line3", "--broker", broker_arg, "--timeout", "1")]
        return accepted[0].returncode == 0

    wait_until(ready, WAIT_S, "the daemon accepting publish_maps")
    assert accepted[0].stdout.strip() == "edgedsm/line3: publish_maps accepted"

    as_json = _cmd("rebaseline", "--device", "line3", "--broker", broker_arg, "--json")
    assert as_json.returncode == 0, as_json.stderr
    reply = json.loads(as_json.stdout)
    assert reply["ok"] is True and reply["command"] == "rebaseline" and reply["request_id"].startswith("cli-")

    refused = _cmd("laser", "--device", "line3", "--broker", broker_arg, "--args", '{"state": "sideways"}')
    assert refused.returncode == 1 and "refused laser" in refused.stderr and "state" in refused.stderr

    unknown = _cmd("explode", "--device", "line3", "--broker", broker_arg, "--json")
    assert unknown.returncode == 1 and json.loads(unknown.stdout)["ok"] is False

    config_file = tmp_path / "edgedsm.toml"
    from_config = _cmd("publish_maps", "-c", str(config_file))
    assert from_config.returncode == 0, from_config.stderr

    silent = _cmd("publish_maps", "--broker", broker_arg, "--timeout", "1")  # default device: nobody there
    assert silent.returncode == 2 and "no reply from edgedsm/camera1 within 1 s" in silent.stderr

    watch = subprocess.run([sys.executable, "-m", "edgedsm", "watch", "--host", "127.0.0.1", "--port",
                            str(broker.port), "--timeout", "3"], capture_output=True, text=True, env=child_env(),
                           timeout=WAIT_S + 20)
    assert watch.returncode == 0, watch.stderr
    assert "watching edgedsm/camera1 (default device name" in watch.stderr
    assert "no daemon has published on edgedsm/camera1 (no availability); devices seen under edgedsm/: line3" \
        in watch.stdout

    bad = _cmd("laser", "--device", "line3", "--broker", broker_arg, "--args", "[1]")
    assert bad.returncode == 65 and "--args must be a JSON object" in bad.stderr
    assert daemon.process.poll() is None  # still measuring


@pytest.mark.timeout(120)
def test_cmd_tells_an_offline_daemon_and_an_unreachable_or_refusing_broker_apart(
        tmp_path: Path, broker: Broker, daemon: Daemon, make_broker: Callable[..., Broker]) -> None:
    broker_arg = f"127.0.0.1:{broker.port}"
    wait_until(lambda: _cmd("publish_maps", "--device", "line3", "--broker", broker_arg, "--timeout", "1")
               .returncode == 0, WAIT_S, "the daemon accepting publish_maps")
    code, _ = daemon.terminate()
    assert code == 0
    started = time.monotonic()
    stopped = _cmd("publish_maps", "--device", "line3", "--broker", broker_arg, "--timeout", "60", "--json")
    took = time.monotonic() - started
    assert stopped.returncode == 2, stopped.stderr
    assert "edgedsm/line3 is offline (its retained availability)" in stopped.stderr
    assert json.loads(stopped.stdout) == {"ok": None, "command": "publish_maps", "error": "offline",
                                          "base": "edgedsm/line3"}
    assert took < 20.0  # at once, not after --timeout 60 (the interpreter's start on a loaded machine included)

    nobody = _cmd("publish_maps", "--device", "line3", "--broker", f"127.0.0.1:{free_port()}")
    assert nobody.returncode == 69, nobody.stderr
    assert "edgedsm: broker unreachable: cannot reach 127.0.0.1:" in nobody.stderr

    passwords = tmp_path / "passwd"
    made = subprocess.run([tool("mosquitto_passwd", "mosquitto"), "-b", "-c", str(passwords), "line3", "s3cret"],
                          capture_output=True, text=True, timeout=30)
    assert made.returncode == 0, made.stderr
    guarded = make_broker(password_file=passwords)
    refused = subprocess.run([sys.executable, "-m", "edgedsm", "cmd", "publish_maps", "--device", "line3",
                              "--broker", f"127.0.0.1:{guarded.port}", "--username", "line3"],
                             capture_output=True, text=True, timeout=WAIT_S + 20,
                             env={**child_env(), "EDGEDSM_MQTT_PASSWORD": "wrong"})
    assert refused.returncode == 78, refused.stderr
    assert "edgedsm: broker refused: " in refused.stderr and "user 'line3'" in refused.stderr
