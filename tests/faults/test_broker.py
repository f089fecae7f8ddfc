"""Fault: the MQTT broker goes away and comes back five times while the plate dries and alerts
are raised (a real mosquitto with persistence, stopped and started again on the same port; the
plant's subscriber keeps a persistent session, as a SCADA client should).

No alert is lost: after deduplication on (stream, seq) the plant has every alert the daemon
raised (counted in its log), seq 1..N in one stream. The daemon keeps measuring throughout and
publishes stats again after each outage. The laser is never switched off for a broker outage.
"""

from __future__ import annotations

import random
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from helpers_daemon import DEMO_PLATE, Daemon
from helpers_faults import TOPICS, Plant, RelayRig, daemon_config
from helpers_mqtt import REPO, Broker

pytestmark = [pytest.mark.faults, pytest.mark.integration, pytest.mark.slow]

DRYING_CAMERA = f"sim:{REPO / 'config' / 'scenes' / 'drying_demo.toml'}?time_scale=0.2"
OUTAGES = 5
TRANSITION = r"region plate: \w+ -> \w+"


@pytest.fixture
def persistent_broker(tmp_path: Path) -> Iterator[Broker]:
    broker = Broker(tmp_path / "broker", persistence=True).start()
    yield broker
    broker.stop()


@pytest.mark.timeout(60)
def test_broker_stopped_and_restarted_five_times_loses_no_alert(
        tmp_path: Path, relay_board: RelayRig, persistent_broker: Broker,
        daemons: Callable[[dict[str, Any]], Daemon]) -> None:
    broker = persistent_broker
    board = relay_board.board
    rng = random.Random(5)
    plant = Plant(broker.port, [TOPICS.alerts, TOPICS.stats], client_id="plant-faults").start()
    try:
        daemon = daemons(daemon_config(tmp_path, camera=DRYING_CAMERA, port=broker.port, laser=relay_board.uri,
                                       window=100, lag=5, **DEMO_PLATE, min_dwell_s=1.0))
        daemon.wait_until(lambda: board.is_on and plant.frames() > 0, 30, "measuring with the laser on")
        lit = board.switched(True, after=0.0)
        downs: list[float] = []
        for _ in range(OUTAGES):
            time.sleep(rng.uniform(1.0, 2.0))
            broker.stop()
            down = rng.uniform(0.5, 1.5)
            downs.append(down)
            time.sleep(down)
            broker.start()
            frames = plant.frames()
            daemon.wait_until(lambda: plant.frames() > frames, 15, "stats again after the broker came back")  # noqa: B023
        # the plate dries on: wait for the last transition (dry) and its alert
        daemon.wait_log(r"region plate: drying -> dry", 30, after=daemon.started)
        daemon.wait_until(lambda: len(plant.distinct_alerts()) >= len(daemon.matching(TRANSITION)), 15,
                          "every alert raised at the plant")
        frames = plant.frames()
        daemon.wait_until(lambda: plant.measuring_since(frames), 10, "measuring after the outages")
        code, _ = daemon.terminate()
    finally:
        plant.stop()
    assert code == 0, daemon.log
    raised = len(daemon.matching(TRANSITION))
    alerts = plant.distinct_alerts()
    print(f"{OUTAGES} broker outages ({', '.join(f'{d:.1f}' for d in downs)} s): {raised} alerts raised, "
          f"{len(alerts)} received after dedup ({len(plant.alerts(TOPICS))} copies)")
    assert raised >= 3
    assert [a["seq"] for a in alerts] == list(range(1, raised + 1)), alerts
    assert len({a["stream"] for a in alerts}) == 1
    assert lit is not None and board.switched(False, after=lit) is not None  # only at the stop
    assert [on for _, on in board.changes] == [True, False], f"the laser switched for a broker outage: {board.changes}"
