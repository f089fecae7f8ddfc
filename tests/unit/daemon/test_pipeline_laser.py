"""Laser safety in the pipeline: the laser state is never guessed, no unlit frame is measured,
the relay is not flooded, a lost or flapping camera leaves the laser off (issue 11)."""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest

from edgedsm.config import load_config
from edgedsm.daemon.devices import couple_simulated_laser
from edgedsm.daemon.pipeline import Cadence, Pipeline
from edgedsm.devices.camera import SimulatedCamera
from edgedsm.devices.laser import SimulatedBoard, SimulatedRelay
from edgedsm.errors import DeviceLost, DeviceTimeout
from edgedsm.messages import AlertKind, Clock
from edgedsm.publish.commands import DarkCommand, LaserCommand
from edgedsm.publish.sink import RecordingSink
from edgedsm.sim import load_scene

DT = 0.05  # pipeline seconds per frame in the frame-count clock


@pytest.fixture
def setup(repo):
    config = load_config(repo / "config" / "daemon" / "demo.toml")
    config.mqtt = None
    scene = load_scene(repo / "config" / "scenes" / "drying_demo.toml")
    scene.scene.size = 64
    relay = SimulatedRelay(SimulatedBoard(readback=True), timeout=0.01)
    return config, scene, relay, RecordingSink()


def hold_back(camera, pipeline, depth=8):
    """The simulated camera waits while the queue holds ``depth`` frames (no drops under load)."""
    grab = camera._do_grab

    def waiting_grab(timeout_s):
        while pipeline.capture.frames.qsize() >= depth and not pipeline.capture.stopping:
            time.sleep(0.001)
        return grab(timeout_s)

    camera._do_grab = waiting_grab


def frame_clock(box: dict) -> Clock:
    """Pipeline time driven by the frame count: runs do not depend on the machine's speed."""
    return Clock(monotonic=lambda: box["p"].counters["frames"] * DT if "p" in box else 0.0)


@contextlib.contextmanager
def running(pipeline: Pipeline, max_frames: int | None = None) -> Iterator[threading.Event]:
    """The pipeline in a thread; stopped (and joined) on exit."""
    stop = threading.Event()
    errors: list[BaseException] = []

    def run() -> None:
        try:
            pipeline.run(stop.is_set, max_frames=max_frames)
        except BaseException as exc:
            errors.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    try:
        yield stop
    finally:
        stop.set()
        thread.join(10)
        assert not thread.is_alive()
    if errors:
        raise errors[0]


def wait_until(predicate, timeout=20.0, what="condition"):
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(0.005)


def lit_pushes(pipeline: Pipeline, relay: SimulatedRelay) -> list[tuple[int, bool]]:
    """Record, for every pushed frame, its count and whether the laser was on at the push."""
    pushed: list[tuple[int, bool]] = []
    pipeline.probes.frame_pushed = lambda frame, t, cost: pushed.append(
        (pipeline.counters["frames"], relay.board.is_on))
    return pushed


# -- the laser state is never guessed -------------------------------------------------------------

def test_a_relay_gone_silent_while_on_makes_the_laser_unknown_and_stops_measuring(setup):
    config, scene, relay, sink = setup
    config.acquisition.dark_frames = 0
    camera = SimulatedCamera(scene, time_scale=0)
    couple_simulated_laser(camera, relay)
    box: dict = {}
    pipeline = box["p"] = Pipeline(config, camera, sink, relay=relay, cadence=Cadence(1.0, 10.0),
                                   clock=frame_clock(box))
    hold_back(camera, pipeline)
    pushed = []
    laser_at_push = []

    def on_taken(frame, count):
        if count == 300:
            relay.board.fail_next(6, "no-answer")  # silent: the contact stays ON meanwhile

    def on_pushed(frame, t, cost):
        pushed.append(pipeline.counters["frames"])
        laser_at_push.append(pipeline.acquisition.laser)

    said: list[tuple[str, bool]] = []  # (laser in the stats, the contact really closed) at each snapshot
    pipeline.probes.frame_taken = on_taken
    pipeline.probes.frame_pushed = on_pushed
    pipeline.probes.snapshot_taken = lambda snapshot, cost: snapshot.publish_stats and said.append(
        (snapshot.status.laser, relay.board.is_on))
    pipeline.run(lambda: False, max_frames=1500)
    lasers = [s.laser for s in sink.stats]
    assert lasers == [laser for laser, _ in said]
    assert "unknown" in lasers, "a silent relay was never noticed"
    # never "off" while the contact is closed: unknown until an off is confirmed
    assert ("off", True) not in said and ("unknown", True) in said
    faults = [a for a in sink.alerts if a.kind == AlertKind.FAULT]
    assert len(faults) == 1 and "relay" in faults[0].reason and "no answer" in faults[0].reason
    assert set(laser_at_push) == {"on"}  # nothing measured while the laser was not known on
    # the switch-off was retried until confirmed, then measuring resumed with the laser on
    assert lasers[-1] == "on" and pushed[-1] > 1000
    assert relay.board.history[-1].on is False and not relay.board.is_on


def test_a_failed_laser_off_command_says_unknown_not_off(setup):
    config, scene, relay, sink = setup
    config.acquisition.dark_frames = 0
    camera = SimulatedCamera(scene, time_scale=0)
    couple_simulated_laser(camera, relay)
    pipeline = Pipeline(config, camera, sink, relay=relay, cadence=Cadence(0.05, 10.0))
    with running(pipeline):
        wait_until(lambda: relay.board.is_on and pipeline.counters["frames"] > 50, what="measuring")
        relay.board.fault = "no-answer"  # dead while ON
        reply = pipeline.submit(LaserCommand(state="off"))
        assert reply.ok is False and "no answer" in (reply.error or "")
        assert reply.laser == "unknown"
        assert pipeline.acquisition.laser == "unknown" and relay.board.is_on
        stats_before = len(sink.stats)
        wait_until(lambda: len(sink.stats) > stats_before + 2, what="stats")
        assert sink.stats[-1].laser == "unknown"
        assert "laser unknown" in pipeline.summary()
        relay.board.fault = "none"
        wait_until(lambda: pipeline.acquisition.laser == "off", what="the retried switch-off confirmed")
        assert not relay.board.is_on
    assert not relay.board.is_on


# -- no unlit frame reaches the estimator ---------------------------------------------------------

def test_a_manual_laser_off_pauses_measuring_without_false_alerts(setup):
    config, scene, relay, sink = setup
    camera = SimulatedCamera(scene, time_scale=0)
    couple_simulated_laser(camera, relay)
    box: dict = {}
    pipeline = box["p"] = Pipeline(config, camera, sink, relay=relay, cadence=Cadence(1.0, 10.0),
                                   clock=frame_clock(box))
    hold_back(camera, pipeline)
    pushed = lit_pushes(pipeline, relay)
    with running(pipeline):
        wait_until(lambda: [a.to_state for a in sink.alerts] == ["wet"] and pipeline.counters["frames"] > 350,
                   what="the plate wet")
        assert pipeline.submit(LaserCommand(state="off")).ok
        off_at = pipeline.counters["frames"]
        alerts_at_off = len(sink.alerts)
        wait_until(lambda: pipeline.counters["frames"] > off_at + 400, what="400 frames with the laser off")
        assert not relay.board.is_on
        assert sink.alerts[alerts_at_off:] == []  # no false wet -> drying from ambient-only frames
        assert pipeline.submit(LaserCommand(state="auto")).ok
        wait_until(lambda: pipeline.counters["frames"] > off_at + 700, what="measuring again")
    assert pushed and all(lit for _, lit in pushed)
    assert not [count for count, _ in pushed if off_at + 5 < count <= off_at + 400]


def test_dark_frames_and_bursts_feed_no_unlit_frame(setup):
    config, scene, relay, sink = setup
    config.acquisition.mode = "bursts"
    config.acquisition.burst_frames = 120
    config.acquisition.burst_period_s = 20.0
    camera = SimulatedCamera(scene, time_scale=0)
    couple_simulated_laser(camera, relay)
    box: dict = {}
    pipeline = box["p"] = Pipeline(config, camera, sink, relay=relay, cadence=Cadence(1.0, 10.0),
                                   clock=frame_clock(box))
    hold_back(camera, pipeline)
    pushed = lit_pushes(pipeline, relay)
    pipeline.run(lambda: False, max_frames=900)
    assert len(pushed) >= 3 * 110 and all(lit for _, lit in pushed)


def test_the_dark_command_takes_dark_frames_even_without_a_schedule(setup):
    config, scene, relay, sink = setup
    assert config.acquisition.dark_every_min == 0
    camera = SimulatedCamera(scene, time_scale=0)
    couple_simulated_laser(camera, relay)
    box: dict = {}
    pipeline = box["p"] = Pipeline(config, camera, sink, relay=relay, cadence=Cadence(1.0, 10.0),
                                   clock=frame_clock(box))
    hold_back(camera, pipeline)
    with running(pipeline):
        wait_until(lambda: pipeline.counters["frames"] > 200, what="measuring")
        first = pipeline.acquisition.last_dark_t
        offs_before = sum(1 for s in relay.board.history if not s.on)
        assert pipeline.submit(DarkCommand()).ok
        wait_until(lambda: pipeline.acquisition.last_dark_t > first, what="dark frames taken")
        wait_until(lambda: relay.board.is_on, what="the laser on again")
    assert sum(1 for s in relay.board.history if not s.on) > offs_before
    assert pipeline.acquisition.ambient_level == pytest.approx(50 * 255 / (1000 + np.sqrt(1000)), rel=0.1)


# -- the relay is not flooded ---------------------------------------------------------------------------

def test_a_flood_of_laser_commands_is_refused_not_executed(setup):
    config, scene, relay, sink = setup
    config.acquisition.dark_frames = 0
    camera = SimulatedCamera(scene, time_scale=0)
    couple_simulated_laser(camera, relay)
    pipeline = Pipeline(config, camera, sink, relay=relay)
    with running(pipeline):
        wait_until(lambda: relay.board.is_on, what="measuring")
        switched = len(relay.board.history)
        started = time.monotonic()
        replies = [pipeline.submit(LaserCommand(state="on" if i % 2 else "off")) for i in range(40)]
        elapsed = time.monotonic() - started
        executed = len(relay.board.history) - switched
    refused = [r for r in replies if not r.ok]
    # at most one switch-on per interval; switching off is never refused (it is the safe side)
    limit = pipeline.acquisition.min_switch_interval_s
    assert executed <= 2 * (elapsed / limit + 1) + 1, (executed, elapsed)
    assert len(refused) >= 15 and all("at most one switch every" in (r.error or "") for r in refused)
    assert all(r.laser in ("on", "off") for r in replies)


# -- a lost or flapping camera ----------------------------------------------------------------------

class StallingCamera(SimulatedCamera):
    """After ``stall_after`` frames the device hangs ``stall_s`` in a grab (longer than the grab
    timeout, as a driver stopping a dead GigE stream does), then reports it lost, once."""

    def __init__(self, *args, stall_after: int, stall_s: float, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.stall_after, self.stall_s = stall_after, stall_s
        self.last_frame_at = 0.0
        self._stalled = False

    def _do_grab(self, timeout_s):
        if self._seq >= self.stall_after and not self._stalled:
            self._stalled = True
            time.sleep(self.stall_s)
            raise DeviceLost("simulated dead stream")
        frame = super()._do_grab(timeout_s)
        self.last_frame_at = time.monotonic()
        return frame


def test_a_lost_camera_switches_the_laser_off_within_grab_timeout(setup):
    config, scene, relay, _ = setup
    config.acquisition.dark_frames = 0
    config.camera.grab_timeout_s = 0.5
    config.camera.reconnect_initial_s = 0.05
    camera = StallingCamera(scene, time_scale=0.05, stall_after=150, stall_s=2.5)
    couple_simulated_laser(camera, relay)
    offs: list[float] = []
    relay.board.add_listener(lambda on: None if on else offs.append(time.monotonic()))
    stats_at: list[tuple[float, str]] = []

    class TimedSink(RecordingSink):
        def publish_stats(self, stats):
            stats_at.append((time.monotonic(), stats.laser))
            super().publish_stats(stats)

    pipeline = Pipeline(config, camera, TimedSink(), relay=relay, cadence=Cadence(5.0, 60.0))
    with running(pipeline):
        wait_until(lambda: camera._stalled, what="the stream stalled")
        wait_until(lambda: bool(offs), timeout=5, what="the laser off")
        wait_until(lambda: any(laser == "off" for _, laser in stats_at), timeout=5, what="stats saying off")
    delay = offs[0] - camera.last_frame_at
    assert delay <= config.camera.grab_timeout_s + 0.3, f"laser off {delay:.2f} s after the last frame"
    said_off = next(t for t, laser in stats_at if laser == "off")
    assert said_off - offs[0] < 0.5  # published at once, not at the next 5 s stats tick


class FlappingCamera(SimulatedCamera):
    """After ``dead_after`` frames the stream dies: it reopens fine but delivers nothing (every
    grab times out) for ``dead_opens`` reopenings, then works again."""

    def __init__(self, *args, dead_after: int, dead_opens: int, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.dead_after, self.dead_opens = dead_after, dead_opens
        self.opens: list[float] = []
        self.dead = False
        self.healed = False
        self.died_at = 0.0

    def _do_open(self):
        self.opens.append(time.monotonic())
        if self.dead and len(self.opens) > self.dead_opens + 1:
            self.dead, self.healed = False, True
        super()._do_open()

    def _do_grab(self, timeout_s):
        if not self.dead and not self.healed and self._seq >= self.dead_after:
            self.dead, self.died_at = True, time.monotonic()
        if self.dead:
            time.sleep(timeout_s)
            raise DeviceTimeout("no frame (simulated dead stream)")
        return super()._do_grab(timeout_s)


def test_a_flapping_camera_is_damped_one_fault_and_the_laser_off_throughout(setup):
    config, scene, relay, sink = setup
    config.acquisition.dark_frames = 0
    config.camera.grab_timeout_s = 0.1
    config.camera.reconnect_initial_s = 0.05
    config.camera.reconnect_max_s = 0.4
    camera = FlappingCamera(scene, time_scale=0.02, dead_after=100, dead_opens=5)
    couple_simulated_laser(camera, relay)
    switches: list[tuple[float, bool]] = []
    relay.board.add_listener(lambda on: switches.append((time.monotonic(), on)))
    pipeline = Pipeline(config, camera, sink, relay=relay, cadence=Cadence(0.2, 60.0))
    with running(pipeline):
        wait_until(lambda: camera.healed, timeout=30, what="the camera healed")
        wait_until(lambda: relay.board.is_on, timeout=10, what="the laser on again")
    reopens = camera.opens[1:]
    gaps = np.diff(reopens)
    # the backoff grows through the outage (0.05, 0.1, 0.2, 0.4 s capped, each after a 0.1 s grab
    # timeout): it does not start over at each reopening that brings no frame
    assert len(reopens) == 6 and gaps[-1] > gaps[0] + 0.25 and np.all(np.diff(gaps) > -0.1), gaps
    ons_in_outage = [t for t, on in switches if on and camera.died_at < t < camera.opens[-1]]
    assert ons_in_outage == []  # laser off while the camera is down
    faults = [a for a in sink.alerts if a.kind == AlertKind.FAULT]
    into_fault = [a for a in sink.alerts if a.to_state == "fault"]
    assert len(faults) == 1 and "camera" in faults[0].reason
    assert len(into_fault) == 1


# -- at stop ------------------------------------------------------------------------------------------

def test_a_laser_not_confirmed_off_at_stop_is_critical_published_and_exit_69(repo, caplog):
    import logging
    import uuid

    from edgedsm.daemon.service import EXIT_LASER_NOT_OFF, Service
    from edgedsm.devices.laser import forget_simulated_boards, simulated_board

    config = load_config(repo / "config" / "daemon" / "demo.toml")
    config.mqtt = None
    name = f"stop-{uuid.uuid4().hex[:8]}"
    config.laser.uri = f"sim:{name}?timeout=0.01"
    board = simulated_board(name)
    service = Service(None, config=config)
    result: dict = {}
    thread = threading.Thread(target=lambda: result.update(code=service.run()), daemon=True)
    try:
        with caplog.at_level(logging.WARNING, logger="edgedsm"):
            thread.start()
            wait_until(lambda: board.is_on, what="measuring")
            board.fault = "no-answer"  # dead while ON
            service.stop()
            thread.join(10)
    finally:
        forget_simulated_boards()
    assert not thread.is_alive() and result["code"] == EXIT_LASER_NOT_OFF == 69
    assert board.is_on  # what the daemon reported: it really is still on
    critical = [r for r in caplog.records if r.levelno == logging.CRITICAL]
    assert len(critical) == 1 and "could not be switched off" in critical[0].getMessage().lower()
    alerts = [r.getMessage() for r in caplog.records if r.getMessage().startswith("alert: fault")]
    assert alerts and "may still be on" in alerts[-1]
    assert service.laser_not_off is not None and "no answer" in service.laser_not_off


def test_a_region_outside_the_frame_is_refused_before_the_laser_goes_on(setup, repo, tmp_path):
    from edgedsm.errors import ConfigError

    _, scene, relay, sink = setup
    text = (repo / "config" / "daemon" / "demo.toml").read_text(encoding="utf-8")
    text = text.replace('name = "plate"', 'name = "plate"\nshape = "rect"\nx = 500\ny = 500\nwidth = 10\nheight = 10')
    text = text.replace("sim:../scenes/", f"sim:{repo / 'config' / 'scenes'}/")
    (tmp_path / "outside.toml").write_text(text, encoding="utf-8")
    config = load_config(tmp_path / "outside.toml")
    config.mqtt = None
    camera = SimulatedCamera(scene, time_scale=0)
    couple_simulated_laser(camera, relay)
    pipeline = Pipeline(config, camera, sink, relay=relay)
    with pytest.raises(ConfigError, match=r"regions\.0: region 'plate' has no pixel inside the 64x64 frame"):
        pipeline.run(lambda: False, max_frames=300)
    assert relay.board.history and not any(s.on for s in relay.board.history)


def test_dark_frames_keep_the_watchdog_fed(setup):
    """A dark phase longer than WatchdogSec must not get the service killed: every frame that
    arrives, dark or lit, counts as alive (issue 11 §8)."""
    config, scene, relay, sink = setup
    config.acquisition.dark_frames = 40
    camera = SimulatedCamera(scene, time_scale=0)
    couple_simulated_laser(camera, relay)
    box: dict = {}
    alive_at: list[int] = []
    pipeline = box["p"] = Pipeline(config, camera, sink, relay=relay, cadence=Cadence(1.0, 10.0),
                                   clock=frame_clock(box),
                                   on_alive=lambda: alive_at.append(box["p"].counters["frames"]))
    hold_back(camera, pipeline)
    pipeline.run(lambda: False, max_frames=60)
    dark = [count for count in alive_at if count <= config.acquisition.dark_frames]
    assert len(set(dark)) >= config.acquisition.dark_frames - 1  # one per dark frame, not one after the phase
