"""Fault: the daemon is killed with SIGKILL (as the OOM killer or a crash in a native library would)
at a random moment while alerts are being raised, and started again on the same state directory,
twice. The plant must lose no alert: after deduplication on (stream, seq), every seq from 1 to
the last is there, in one stream. The restarted daemon switches the laser off before anything
else (an emulated Numato board on a PTY).

The moments are drawn from a seed printed in every failure message; set EDGEDSM_FAULT_SEED to
replay one.
"""

from __future__ import annotations

import os
import random
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from helpers_daemon import DEMO_PLATE, Daemon
from helpers_faults import Plant, RelayRig, daemon_config
from helpers_mqtt import REPO, Broker

pytestmark = [pytest.mark.faults, pytest.mark.integration, pytest.mark.slow]

#: The demo plate at 100 frames/s: wet → drying → dry in about 12 s.
DRYING_CAMERA = f"sim:{REPO / 'config' / 'scenes' / 'drying_demo.toml'}?time_scale=0.2"
KILLS = 3
#: A kill comes up to this long after the daemon logged an alert: while it is being stored and sent.
LATEST_KILL_S = 0.5


@pytest.mark.timeout(60)
def test_sigkill_at_random_moments_then_restart_loses_no_alert(
        tmp_path: Path, relay_board: RelayRig, broker: Broker, plant: Plant,
        daemons: Callable[[dict[str, Any]], Daemon]) -> None:
    seed = int(os.environ.get("EDGEDSM_FAULT_SEED", time.time_ns() % 2**32))
    rng = random.Random(seed)
    board = relay_board.board
    config = daemon_config(tmp_path, camera=DRYING_CAMERA, port=broker.port, laser=relay_board.uri, window=100,
                           lag=5, **DEMO_PLATE, min_dwell_s=1.0)

    moments: list[float] = []
    daemon = daemons(config)
    for kill in range(1, KILLS + 1):
        daemon.wait_log(r"region plate: \w+ -> \w+", 30, after=daemon.started)
        delay = rng.uniform(0.0, LATEST_KILL_S)
        moments.append(delay)
        time.sleep(delay)
        daemon.kill()
        killed = time.monotonic()
        daemon = daemons(config)
        # the new daemon's first command to the relay switches the laser off
        daemon.wait_until(lambda: board.first_command(after=killed) is not None, 20,  # noqa: B023
                          f"the restarted daemon switching the relay (seed {seed})")
        assert board.first_command(after=killed) is False, \
            f"the first command after restart {kill} switched the laser on (seed {seed}): {board.commands}"

    seen = len(plant.distinct_alerts())
    daemon.wait_until(lambda: len(plant.distinct_alerts()) > seen, 30, f"an alert after the last restart (seed {seed})")
    code, _ = daemon.terminate()
    assert code == 0, daemon.log
    time.sleep(0.3)  # anything still in flight
    alerts = plant.distinct_alerts()
    seqs = [a["seq"] for a in alerts]
    assert seqs == list(range(1, len(seqs) + 1)), f"alerts lost (seed {seed}): seqs {seqs}"
    assert len({a["stream"] for a in alerts}) == 1, f"one alert stream across restarts (seed {seed})"
    assert not board.is_on
    print(f"seed {seed}: killed {', '.join(f'{m:.2f}' for m in moments)} s after an alert was raised; "
          f"{len(alerts)} alerts, none lost")
