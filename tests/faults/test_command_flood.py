"""Fault: a command flood — 500 `laser`/`dark`/`rebaseline`/garbage commands in a few seconds from a
misbehaving client holding a command key (the commands are signed) — against the running daemon
(real mosquitto, a Numato board on a PTY).

Every request gets a reply or a refusal (none lost), the relay is switched on at most once per
``MIN_SWITCH_INTERVAL_S`` (counted on the board's side: its 'relay on' commands), and the daemon
measures again once the flood is over. No alert is lost.
"""

from __future__ import annotations

import json
import random
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from helpers_commands import signed
from helpers_daemon import Daemon
from helpers_faults import TOPICS, Plant, RelayRig, daemon_config
from helpers_mqtt import REPO, Broker, Subscriber

from edgedsm.daemon.acquisition import MIN_SWITCH_INTERVAL_S

pytestmark = [pytest.mark.faults, pytest.mark.integration, pytest.mark.slow]

CAMERA = f"sim:{REPO / 'config' / 'scenes' / 'drying_demo.toml'}?time_scale=0.2"
COMMANDS = 500
FLOOD_S = 3.0


def flood(rng: random.Random) -> list[tuple[str, bytes]]:
    """(command name, payload) of the flood; JSON requests carry a request_id ``f<i>``."""
    out: list[tuple[str, bytes]] = []
    for i in range(COMMANDS):
        kind = rng.choice(["laser", "laser", "laser", "dark", "rebaseline", "garbage", "unknown"])
        if kind == "laser":
            state = rng.choice(["on", "off", "auto", "dim"])
            out.append(("laser", signed(TOPICS.command("laser"), {"state": state}, request_id=f"f{i}").encode()))
        elif kind in ("dark", "rebaseline"):
            out.append((kind, signed(TOPICS.command(kind), request_id=f"f{i}").encode()))
        elif kind == "garbage":
            out.append((rng.choice(["laser", "dark"]), bytes(rng.getrandbits(8) for _ in range(rng.randint(1, 40)))))
        else:
            out.append(("self_destruct", json.dumps({"request_id": f"f{i}"}).encode()))
    return out


@pytest.mark.timeout(60)
def test_command_flood_every_request_answered_relay_rate_limited(
        tmp_path: Path, relay_board: RelayRig, broker: Broker, plant: Plant,
        daemons: Callable[[dict[str, Any]], Daemon]) -> None:
    board = relay_board.board
    config = daemon_config(tmp_path, camera=CAMERA, port=broker.port, laser=relay_board.uri)
    config["acquisition"]["dark_frames"] = 2
    daemon = daemons(config)
    daemon.wait_until(lambda: plant.measuring_since(0) and board.is_on, 30, "measuring with the laser on")
    replies = Subscriber(broker.port, [f"{TOPICS.base}/cmd/+/reply"]).start()
    sender = Subscriber(broker.port, [f"{TOPICS.base}/nothing"]).start()
    try:
        requests = flood(random.Random(11))
        started = time.monotonic()
        for i, (name, payload) in enumerate(requests):
            sender.client.publish(TOPICS.command(name), payload, qos=1)
            time.sleep(max(0.0, started + FLOOD_S * (i + 1) / COMMANDS - time.monotonic()))
        sent = time.monotonic()
        daemon.wait_until(lambda: len(replies.messages) >= COMMANDS, 30, f"{COMMANDS} replies")
        answered = time.monotonic()
        time.sleep(0.5)  # a reply too many would show up now
        got = [m.json() for m in replies.messages]
        # the flood may have ended on `laser off` (held): hand the laser back to the plan
        for attempt in range(10):
            sender.client.publish(TOPICS.command("laser"),
                                  signed(TOPICS.command("laser"), {"state": "auto"}, request_id=f"a{attempt}"), qos=1)
            reply = replies.wait_for(TOPICS.reply("laser"), lambda m: m.json()["request_id"] == f"a{attempt}",  # noqa: B023
                                     "the reply to laser auto").json()
            if reply["ok"]:
                break
            time.sleep(MIN_SWITCH_INTERVAL_S)
        frames = plant.frames()
        daemon.wait_until(lambda: plant.measuring_since(frames) and board.is_on, 20, "measuring after the flood")
    finally:
        sender.stop()
        replies.stop()
    code, _ = daemon.terminate()
    assert code == 0, daemon.log

    assert len(got) == COMMANDS
    ids = {f"f{i}" for i, (_, p) in enumerate(requests) if p.startswith(b"{")}
    assert ids <= {r["request_id"] for r in got}, "a JSON request got no reply"
    refused = [r for r in got if not r["ok"]]
    assert all(isinstance(r["error"], str) and r["error"] for r in refused)
    ons = [t for t, on in board.commands if on and started <= t <= answered]
    allowed = int((answered - started) / MIN_SWITCH_INTERVAL_S) + 1
    busy = sum("busy" in r["error"] for r in refused)
    rate = sum("rate limited" in r["error"] for r in refused)
    print(f"{COMMANDS} commands in {sent - started:.1f} s, all answered after {answered - started:.1f} s: "
          f"{len(got) - len(refused)} ok, {len(refused)} refused ({busy} busy, {rate} rate limited); "
          f"relay switched on {len(ons)} times (at most {allowed} allowed)")
    assert len(ons) <= allowed, board.commands
    alerts = plant.distinct_alerts()
    assert [a["seq"] for a in alerts] == list(range(1, len(alerts) + 1)), alerts
    assert not board.is_on
