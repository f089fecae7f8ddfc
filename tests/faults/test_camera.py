"""Fault: the camera loses power in mid-run, twice, and comes back (Aravis' fake GigE Vision camera
as a process, killed with SIGKILL and started again; the daemon opens it by its device id).

For each outage: the laser (a PTY-emulated Numato board) goes off within grab_timeout_s + 0.5 s
of the kill and stays off while the camera is down; the plant gets one fault alert per outage
(not one per reconnection attempt); once the camera is back the daemon measures again (new
frames, a measured state, the laser on). No alert is lost (after deduplication).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from helpers_aravis import FakeGvCamera
from helpers_daemon import Daemon
from helpers_faults import Plant, RelayRig, daemon_config
from helpers_mqtt import Broker

pytestmark = [pytest.mark.faults, pytest.mark.integration, pytest.mark.slow]

GRAB_TIMEOUT_S = 2.0
LASER_OFF_BOUND_S = GRAB_TIMEOUT_S + 0.5
DOWN_S = 3.0  # the camera stays dead this long: several reconnection attempts fail meanwhile
OUTAGES = 2


def _stats_between(plant: Plant, start_wall: float, end_wall: float) -> list[dict[str, Any]]:
    return [s for s in plant.stats() if start_wall < s["t"] < end_wall]


# alone: one outage per kill is judged on the camera's 2 s grab timeout; another test taking the
# cores can hold the capture thread past it after the restart, which is a second outage
@pytest.mark.alone
@pytest.mark.timeout(60)
def test_fake_gige_camera_killed_and_restarted_twice(
        tmp_path: Path, fake_gige: Callable[..., FakeGvCamera], relay_board: RelayRig, broker: Broker,
        plant: Plant, daemons: Callable[[dict[str, Any]], Daemon]) -> None:
    fake = fake_gige()
    board = relay_board.board
    daemon = daemons(daemon_config(tmp_path, camera=f"aravis:{fake.device_id}", port=broker.port,
                                   laser=relay_board.uri, frame_interval_s=0.05, grab_timeout_s=GRAB_TIMEOUT_S))
    daemon.wait_until(lambda: plant.measuring_since(0) and board.is_on, 30, "measuring with the laser on")

    off_delays: list[float] = []
    relit_delays: list[float] = []
    for outage in range(1, OUTAGES + 1):
        killed = fake.kill()
        assert killed is not None
        daemon.wait_until(lambda: board.switched(False, after=killed) is not None,  # noqa: B023 (called at once)
                          LASER_OFF_BOUND_S + 5, f"the laser off after camera kill {outage}")
        off = board.switched(False, after=killed)
        assert off is not None
        off_delays.append(off - killed)
        wall_off = time.time()
        time.sleep(DOWN_S)
        frames_down = plant.frames()
        restarted, wall_restarted = time.monotonic(), time.time()
        fake.start(wait=False)
        daemon.wait_until(lambda: plant.measuring_since(frames_down) and board.is_on,  # noqa: B023
                          25, f"measuring again with the laser on after restart {outage}")
        relit = board.switched(True, after=restarted)
        assert relit is not None
        relit_delays.append(relit - restarted)
        # while the camera was down: the laser stayed off, and the plant was told so
        assert not board.on_between(off, restarted), board.changes
        down = _stats_between(plant, wall_off + 0.6, wall_restarted)
        assert down, "no stats while the camera was down"
        assert all(s["laser"] == "off" and s["state"]["plate"] == "fault" for s in down), down
        # the daemon's log too: which path raised an extra fault is in it (seen once in CI)
        assert len(plant.fault_alerts()) == outage, (plant.distinct_alerts(), daemon.log[-6000:])

    code, _ = daemon.terminate()
    assert code == 0, daemon.log
    print(f"laser off after the camera kills: {', '.join(f'{d:.2f}' for d in off_delays)} s "
          f"(grab_timeout_s {GRAB_TIMEOUT_S}); on again after the restarts: "
          f"{', '.join(f'{d:.2f}' for d in relit_delays)} s")
    assert all(delay <= LASER_OFF_BOUND_S for delay in off_delays), \
        f"laser off {', '.join(f'{d:.2f}' for d in off_delays)} s after the kills (bound {LASER_OFF_BOUND_S} s)"
    alerts = plant.distinct_alerts()
    assert [a["seq"] for a in alerts] == list(range(1, len(alerts) + 1)), alerts
    assert len(plant.fault_alerts()) == OUTAGES
    assert not board.is_on


FLAPPING_S = 20.0  # how long the camera opens fine but delivers nothing


@pytest.mark.timeout(60)
def test_camera_that_opens_but_delivers_nothing_is_damped(
        tmp_path: Path, fake_gige: Callable[..., FakeGvCamera], relay_board: RelayRig, broker: Broker,
        plant: Plant, daemons: Callable[[dict[str, Any]], Daemon]) -> None:
    """The camera comes back with every stream packet lost (a broken link or MTU): each reopen
    succeeds, no frame ever arrives. That is one outage: one fault alert, the laser not cycled
    on and off at every reconnection. When the link is mended the daemon measures again."""
    healthy = fake_gige()
    board = relay_board.board
    config = daemon_config(tmp_path, camera=f"aravis:{healthy.device_id}", port=broker.port, laser=relay_board.uri,
                           frame_interval_s=0.05, grab_timeout_s=GRAB_TIMEOUT_S)
    config["camera"]["reconnect_max_s"] = 8.0
    daemon = daemons(config)
    daemon.wait_until(lambda: plant.measuring_since(0) and board.is_on, 30, "measuring with the laser on")
    alerts_before = len(plant.distinct_alerts())

    killed = healthy.kill()
    assert killed is not None
    broken = fake_gige(lost_per_thousand=1000)  # the same camera, now on a link that loses every packet
    time.sleep(FLAPPING_S)
    alerts = plant.distinct_alerts()[alerts_before:]
    faults = [a for a in plant.fault_alerts() if a in alerts]
    ons = [t for t, on in board.commands if on and t > killed]
    reopened = len(daemon.matching(r"camera reconnected"))
    print(f"in {FLAPPING_S:.0f} s of a camera delivering nothing: {reopened} reconnections, {len(ons)} laser-on "
          f"commands, {len(alerts)} alerts")

    broken.kill()
    frames_down = plant.frames()
    fake_gige()  # mended
    daemon.wait_until(lambda: plant.measuring_since(frames_down) and board.is_on, 25, "measuring again")
    code, _ = daemon.terminate()
    assert code == 0, daemon.log
    assert len(faults) == 1, f"one fault alert for one outage, not one per reconnection: {alerts}"
    assert not [a for a in alerts if a.get("from") == "fault"], f"the fault never cleared meanwhile: {alerts}"
    assert len(ons) <= 2, f"the laser was switched on {len(ons)} times while no frame arrived"
