"""Fault: the laser relay (a Numato board with readback, emulated on a socat PTY) fails mid-run
while the laser is ON: it answers garbage, or it is unplugged (the PTY closed) and plugged in again
(a new PTY on the same path). A board gone silent is covered in tests/integration/test_daemon_e2e.py.

For each: the daemon says ``laser: unknown`` (never ``off`` while not confirmed), raises one fault
alert, stops measuring (no state change while unknown), retries switching off; once the board
answers properly again it confirms off, switches on and measures again. No alert is lost.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from helpers_daemon import Daemon
from helpers_faults import NUMATO_CHANNEL, Plant, RecordingNumato, RelayRig, daemon_config
from helpers_mqtt import REPO, Broker
from helpers_relay import open_pty_pair

pytestmark = [pytest.mark.faults, pytest.mark.integration, pytest.mark.slow]

CAMERA = f"sim:{REPO / 'config' / 'scenes' / 'drying_demo.toml'}?time_scale=0.2"
#: The readback is checked every 5 s (acquisition.RELAY_CHECK_S), plus the driver's 0.3 s timeout
#: and the first off retry (0.5 s): a broken board is noticed and switched off within this.
NOTICE_BOUND_S = 5.0 + 0.3 + 0.5 + 1.5
FAULT_S = 3.0  # how long the board stays broken once the daemon noticed


def _lasers(plant: Plant, after_wall: float) -> list[str]:
    return [s["laser"] for s in plant.stats() if s["t"] > after_wall]


def _unknown_then_measuring(plant: Plant, daemon: Daemon, broken_wall: float, what: str) -> list[dict[str, Any]]:
    """Wait for stats saying unknown after ``broken_wall``; return the stats published while unknown."""
    daemon.wait_until(lambda: "unknown" in _lasers(plant, broken_wall), NOTICE_BOUND_S + 5,
                      f"stats saying the laser is unknown ({what})")
    return [s for s in plant.stats() if s["t"] > broken_wall and s["laser"] == "unknown"]


@pytest.mark.timeout(60)
def test_relay_answering_garbage_while_on(tmp_path: Path, relay_board: RelayRig, broker: Broker, plant: Plant,
                                          daemons: Callable[[dict[str, Any]], Daemon]) -> None:
    board = relay_board.board
    daemon = daemons(daemon_config(tmp_path, camera=CAMERA, port=broker.port, laser=relay_board.uri))
    daemon.wait_until(lambda: plant.measuring_since(0) and board.is_on, 30, "measuring with the laser on")

    broken, broken_wall = time.monotonic(), time.time()
    board.mode = "garbage"  # answers nonsense, still switches
    unknown = _unknown_then_measuring(plant, daemon, broken_wall, "garbage")
    daemon.wait_until(lambda: board.switched(False, after=broken) is not None, NOTICE_BOUND_S, "the relay off")
    off = board.switched(False, after=broken)
    assert off is not None
    time.sleep(FAULT_S)
    # every answer is garbage: the daemon cannot confirm off, so it never says off, never relights
    assert set(_lasers(plant, broken_wall)) <= {"on", "unknown"}, _lasers(plant, broken_wall)
    assert not board.on_between(off, time.monotonic()), board.changes
    unknown = [s for s in plant.stats() if s["t"] > broken_wall and s["laser"] == "unknown"]
    assert len(unknown) >= 4 and all(s["state"]["plate"] not in ("wet", "drying", "dry") or
                                     s["state"]["plate"] == unknown[0]["state"]["plate"] for s in unknown)
    faults = plant.fault_alerts()
    assert len(faults) == 1 and "relay" in faults[0]["reason"], faults

    mended = time.monotonic()
    frames = plant.frames()
    board.mode = "normal"
    daemon.wait_until(lambda: plant.measuring_since(frames) and board.is_on, 40, "measuring again")
    relit = board.switched(True, after=mended)
    code, _ = daemon.terminate()
    assert code == 0, daemon.log
    alerts = plant.distinct_alerts()
    assert [a["seq"] for a in alerts] == list(range(1, len(alerts) + 1)), alerts
    assert not board.is_on
    print(f"garbage relay: off {off - broken:.2f} s after it broke; on again {relit - mended:.2f} s after mending "
          f"(bound {NOTICE_BOUND_S:.1f} s)")
    assert off - broken <= NOTICE_BOUND_S


@pytest.mark.timeout(60)
def test_relay_unplugged_while_on_then_plugged_in_again(tmp_path: Path, broker: Broker, plant: Plant,
                                                        daemons: Callable[[dict[str, Any]], Daemon]) -> None:
    """Unplugging closes the PTY under the driver (its reads and writes fail); plugging in again
    makes a new PTY at the same path, with a board that powers up off. The daemon must reopen it."""
    ports = tmp_path / "ports"
    ports.mkdir()
    uri = f"serial:{ports / 'app'}?protocol=numato&channel={NUMATO_CHANNEL}&timeout=0.3"
    with open_pty_pair(ports) as pair:
        board = RecordingNumato(pair.board, NUMATO_CHANNEL)
        board.start()
        daemon = daemons(daemon_config(tmp_path, camera=CAMERA, port=broker.port, laser=uri))
        daemon.wait_until(lambda: plant.measuring_since(0) and board.is_on, 30, "measuring with the laser on")
        unplugged_wall = time.time()
        board.stop()
    assert board.errors == []
    unknown = _unknown_then_measuring(plant, daemon, unplugged_wall, "unplugged")
    time.sleep(FAULT_S)
    assert "off" not in _lasers(plant, unplugged_wall), "laser said off although nothing confirmed it"
    faults = plant.fault_alerts()
    assert len(faults) == 1 and "relay" in faults[0]["reason"], faults
    assert unknown

    with open_pty_pair(ports) as pair:  # plugged in again: a new PTY behind the same path
        board = RecordingNumato(pair.board, NUMATO_CHANNEL)
        board.start()
        plugged = time.monotonic()
        frames = plant.frames()
        try:
            daemon.wait_until(lambda: plant.measuring_since(frames) and board.is_on, 40,
                              "measuring again on the board plugged in again")
            assert board.first_command(after=plugged) is False, board.commands  # confirmed off first
            code, _ = daemon.terminate()
        finally:
            board.stop()
    assert board.errors == []
    assert code == 0, daemon.log
    assert not board.is_on
    alerts = plant.distinct_alerts()
    assert [a["seq"] for a in alerts] == list(range(1, len(alerts) + 1)), alerts
