"""Fault: a SIGHUP storm — 20 reloads in about 5 s, alternating a good file and a bad one (not
UTF-8, a relay device that does not exist, a region outside the frame, an empty file) — on a
running daemon with a Numato board on a PTY.

The daemon never exits, refuses each bad file with its reason (in the log and as a warning alert),
keeps measuring on the last good configuration, and the laser is switched on only to measure: at
most once per rebuilt pipeline. No alert is lost.
"""

from __future__ import annotations

import copy
import signal
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from helpers_daemon import Daemon, write_config
from helpers_faults import Plant, RelayRig, daemon_config
from helpers_mqtt import REPO, Broker

pytestmark = [pytest.mark.faults, pytest.mark.integration, pytest.mark.slow]

CAMERA = f"sim:{REPO / 'config' / 'scenes' / 'drying_demo.toml'}?time_scale=0.2"
RELOADS = 20
PACE_S = 0.25  # 20 reloads in 5 s when each is handled at once
OUTCOME_S = 10.0  # a reload is refused or applied within this
# the reply to a SIGHUP, not the "configuration reloaded, measurement restarted" line that an applied
# reload logs later (under load, after the next SIGHUP was sent)
OUTCOME = r"reload refused|configuration reloaded from"


def bad_files(good: dict[str, Any], tmp_path: Path) -> list[tuple[str, bytes | dict[str, Any], str]]:
    """(what, content, a word of the expected refusal)."""
    missing_relay = copy.deepcopy(good)
    missing_relay["laser"]["uri"] = f"serial:{tmp_path / 'no-such-tty'}?protocol=numato&channel=11"
    outside = copy.deepcopy(good)
    outside["regions"][0].update(shape="rect", x=500.0, y=500.0, width=20.0, height=20.0)
    return [("not UTF-8", b"[device]\nname = \"\xff\xfe\x00bad\"\n", "UTF-8"),
            ("missing relay device", missing_relay, "no-such-tty"),
            ("region outside the frame", outside, "inside"),
            ("empty file", b"", "camera")]


@pytest.mark.timeout(90)
def test_sighup_storm_of_good_and_bad_files(tmp_path: Path, relay_board: RelayRig, broker: Broker, plant: Plant,
                                            daemons: Callable[[dict[str, Any]], Daemon]) -> None:
    board = relay_board.board
    good = daemon_config(tmp_path, camera=CAMERA, port=broker.port, laser=relay_board.uri)
    path = tmp_path / "daemon.toml"
    daemon = daemons(good)
    daemon.wait_until(lambda: plant.measuring_since(0) and board.is_on, 30, "measuring with the laser on")
    ons_before = sum(on for _, on in board.commands)
    bad = bad_files(good, tmp_path)
    outcomes: list[tuple[str, str]] = []
    started = time.monotonic()
    for i in range(RELOADS):
        if i % 2 == 0:
            variant = copy.deepcopy(good)
            variant["regions"][0]["dry_below"] = 1e5 * (1 + i / 100)  # good, and different each time
            write_config(path, variant)
            what, expected = "good", "reloaded"
        else:
            what, content, expected = bad[(i // 2) % len(bad)]
            if isinstance(content, bytes):
                partial = path.with_name("partial")
                partial.write_bytes(content)
                partial.replace(path)
            else:
                write_config(path, content)
        sent = time.monotonic()
        daemon.process.send_signal(signal.SIGHUP)
        daemon.wait_log(OUTCOME, OUTCOME_S, after=sent)
        line = next(line for t, line in daemon.matching(OUTCOME) if t > sent)
        outcomes.append((what, line))
        assert daemon.process.poll() is None, daemon.log
        assert ("reloaded" in line) == (expected == "reloaded"), f"reload {i} ({what}): {line}"
        time.sleep(max(0.0, started + PACE_S * (i + 1) - time.monotonic()))
    storm_s = time.monotonic() - started
    write_config(path, good)

    frames = plant.frames()
    daemon.wait_until(lambda: plant.measuring_since(frames) and board.is_on, 20, "measuring after the storm")
    assert daemon.process.poll() is None
    ons = sum(on for _, on in board.commands) - ons_before
    refusals = [a for a in plant.distinct_alerts() if "reload refused" in (a.get("reason") or "")]
    code, _ = daemon.terminate()
    assert code == 0, daemon.log
    good_reloads = sum("reloaded" in line for _, line in outcomes)
    refused = [(what, line) for what, line in outcomes if "refused" in line]
    print(f"{RELOADS} reloads in {storm_s:.1f} s: {good_reloads} applied, {len(refused)} refused, "
          f"{len(refusals)} refusal alerts; laser switched on {ons} times")
    assert good_reloads == RELOADS // 2
    assert [what for what, _ in refused] == [bad[k % len(bad)][0] for k in range(RELOADS // 2)]
    assert len(refusals) == RELOADS // 2
    for k, alert in enumerate(refusals):  # each with its own reason
        assert bad[k % len(bad)][2] in alert["reason"], (bad[k % len(bad)][0], alert["reason"])
    assert ons <= good_reloads + 1, board.commands
    alerts = plant.distinct_alerts()
    assert [a["seq"] for a in alerts] == list(range(1, len(alerts) + 1)), alerts
    assert not board.is_on
