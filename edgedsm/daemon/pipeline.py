"""The measurement pipeline: camera → bounded queue → streaming estimator → region statistics →
drying-state machine → typed messages to one sink, with the laser switched as the acquisition
plan says.

Composed of :mod:`capture` (the capture thread and its drop-oldest queue, camera reconnection),
:mod:`acquisition` (laser, dark frames, bursts: whether frames are wanted now),
:mod:`measurement` (the engine and the regions, on the pipeline thread: a snapshot at each
evaluation) and :mod:`evaluator` (statistics, drying states and messages on the evaluator thread).

Threads: the capture thread fills the queue; the thread that calls :meth:`Pipeline.run` (the
pipeline thread) takes frames, drives the laser and the engine, handles commands (queued to it
from the MQTT thread by :meth:`Pipeline.submit`) and owns the stats and maps cadence; the
evaluator thread analyses snapshots and publishes. The drying monitor, which commands reset and
the evaluator steps, is guarded by a lock; everything else has a single owning thread.

Frames come first: while a paced camera's queue is half full, the statistics and maps wait (up
to ``POSTPONE_MAX_INTERVALS`` stats intervals; the drying states go on), so that a machine
slower for a while catches up instead of dropping frames.

Every time published is wall-clock UTC, converted once from the monotonic clock
(:meth:`edgedsm.messages.Clock.to_wall`).

Laser safety: the laser is switched on only while frames are wanted, and off when the camera
is down (no frame within ``camera.grab_timeout_s``, whatever the driver says), during dark
frames, between bursts, at stop and on any error (``run`` switches it off in a ``finally``; the
service wraps the whole in ``LaserSafety``). A camera outage is over only once frames have
flowed for ``CAMERA_STABLE_S``: a flapping camera is one outage, one fault, the laser off
throughout.
"""

from __future__ import annotations

import logging
import queue
import time
from collections import Counter
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any

from edgedsm.config import CadenceSection, DaemonConfig
from edgedsm.daemon.acquisition import Acquisition
from edgedsm.daemon.capture import Capture
from edgedsm.daemon.engine_budget import warm_up
from edgedsm.daemon.evaluator import Evaluator
from edgedsm.daemon.handover import Status
from edgedsm.daemon.measurement import Measurement
from edgedsm.daemon.probes import PipelineProbes
from edgedsm.daemon.recording import Recorder
from edgedsm.daemon.tau import TauRegions
from edgedsm.devices.camera.base import Camera
from edgedsm.devices.laser.base import LaserRelay
from edgedsm.errors import EdgedsmError
from edgedsm.frames import Frame
from edgedsm.messages import Alert, AlertKind, Clock
from edgedsm.publish.commands import (
    Command,
    CommandResult,
    DarkCommand,
    LaserCommand,
    PublishMapsCommand,
    RebaselineCommand,
    RecordCommand,
)
from edgedsm.publish.sink import Sink

log = logging.getLogger(__name__)

#: Plain S2 is judged unreliable (paper §2B) when the ambient level exceeds this fraction of
#: the mean lit level.
AMBIENT_S2_WARNING = 0.1
#: Frames the rate (``fps``) is measured over.
FPS_FRAMES = 64
#: How long frames must flow again after a camera outage before the laser goes back on (s).
CAMERA_STABLE_S = 1.0
#: A paced camera's queue at least this full (fraction of its length) makes the statistics and
#: maps wait, the frames first (drying states go on): an evaluation is worth less than a frame.
POSTPONE_QUEUE_FILL = 0.5
#: ... for at most this many stats intervals: an overloaded daemon still publishes its statistics
#: (and with them its drop counters).
POSTPONE_MAX_INTERVALS = 4


@dataclass
class Cadence:
    """How often the pipeline evaluates and publishes (seconds of the monotonic clock); the
    drying states are judged every ``states_every_s`` whatever the stats interval."""

    stats_every_s: float
    maps_every_s: float
    states_every_s: float = 0.5

    @classmethod
    def of(cls, section: CadenceSection) -> Cadence:
        """The configuration's ``[cadence]`` (its defaults are the daemon's: one place for them)."""
        return cls(stats_every_s=section.stats_interval_s, maps_every_s=section.maps_interval_s)


def next_due(due: float, every_s: float, now: float) -> float:
    """When a cadence is next due after it ran at ``now`` (due at ``due``): one period after the
    time it was due, so that a loop that notices it a frame late keeps the cadence's rate (a
    period counted from ``now`` would lose the lateness every time: 1.9 evaluations/s for 2 at
    25 frames/s); from ``now`` when it ran more than a period late (no burst to catch up)."""
    return due + every_s if now - due < every_s else now + every_s


class Pipeline:
    """One camera's measurement loop (see the module docstring)."""

    def __init__(self, config: DaemonConfig, camera: Camera, sink: Sink, relay: LaserRelay | None = None,
                 cadence: Cadence | None = None, clock: Clock | None = None,
                 on_alive: Callable[[], None] | None = None, probes: PipelineProbes | None = None,
                 recorder: Recorder | None = None) -> None:
        self.config = config
        self.recorder = recorder  # [recording]: offered every frame taken (never waits on the disk)
        self.camera = camera
        self.sink = sink
        self.cadence = cadence or Cadence.of(config.cadence)
        self.clock = clock or Clock()
        self.on_alive = on_alive or (lambda: None)
        self.probes = probes or PipelineProbes()
        self.counters: Counter[str] = Counter()
        self.capture = Capture(camera, config.camera, config.acquisition, self.counters, self.probes)
        tau = TauRegions(config)  # τc: frame interval, region pixels (edgedsm.daemon.tau); both threads read it
        self.evaluator = Evaluator(config, tau, sink, self.clock, self.counters, self.probes)
        self.measurement = Measurement(config, tau, self.evaluator.map_buffers, self.counters, self.probes)
        self.acquisition = Acquisition(config.acquisition, relay, self.counters, self.clock.monotonic,
                                       on_fault=self._device_fault,
                                       relit=lambda: self.restart("laser on", states=False),
                                       burst_ended=lambda now: self._evaluate(now), drain=self.capture.drain,
                                       camera_lost=self.capture.lost.is_set)
        self.lit_level: float | None = None
        self._commands: queue.Queue[tuple[Command, Future[CommandResult]]] = queue.Queue()
        #: each command type and its handler (run on the pipeline thread)
        self._handlers: dict[type[Command], Callable[[Any], CommandResult]] = {
            LaserCommand: self._laser, RebaselineCommand: self._rebaseline, DarkCommand: self._dark,
            PublishMapsCommand: self._publish_maps, RecordCommand: self._record}
        self._last_frame_t: float | None = None  # None until the first frame
        self._stats_due = float("-inf")  # when the next stats are due (monotonic)
        self._states_due = float("-inf")  # and the next drying states
        self._stats_owed = False  # stats were due but the evaluator was busy (or frames came first)
        self._last_stats_t = float("-inf")  # when stats were last handed over
        self._postponing = False  # statistics wait for the queue to drain (_frames_first)
        self._postpone_logged_t = float("-inf")
        self._last_maps_t = float("-inf")
        self._frames_t: list[float] = []
        self._losses_seen = 0
        self._outage: str | None = None  # why the camera is down (None: it is up)
        self._back_since: float | None = None  # frames flowing again since (during an outage)
        self._fault: str | None = None  # reported at the next evaluation, then cleared
        self._camera_ok = False  # as last judged by _watch_camera
        self._urgent = False  # evaluate at once (the laser or the camera changed), whatever the cadence

    # -- commands (called from other threads) -------------------------------------------------
    def submit(self, command: Command, timeout_s: float = 5.0) -> CommandResult:
        """Run a validated command on the pipeline thread and wait (bounded) for its result."""
        future: Future[CommandResult] = Future()
        self._commands.put((command, future))
        try:
            return future.result(timeout=timeout_s)
        except TimeoutError:
            return CommandResult.refused(f"command {type(command).__name__} not handled within {timeout_s} s")

    def _handle_commands(self) -> None:
        while True:
            try:
                command, future = self._commands.get_nowait()
            except queue.Empty:
                return
            handler = self._handlers.get(type(command))
            try:
                if handler is None:
                    raise EdgedsmError(f"no handler for {type(command).__name__}")
                future.set_result(handler(command))
            except EdgedsmError as exc:
                future.set_result(CommandResult.refused(str(exc)))
            except Exception as exc:  # a command must never take the measurement down
                log.exception("command %s failed", type(command).__name__)
                future.set_result(CommandResult.refused(f"internal error: {exc}"))

    def _laser(self, command: LaserCommand) -> CommandResult:
        before = self.acquisition.laser
        result = self.acquisition.command(command.state, self.clock.monotonic(), self._camera_ok)
        self._urgent = self._urgent or self.acquisition.laser != before
        return result

    def _rebaseline(self, command: RebaselineCommand) -> CommandResult:
        self.restart("command rebaseline")
        return CommandResult()

    def _dark(self, command: DarkCommand) -> CommandResult:
        refusal = self.acquisition.dark_refusal()
        if refusal is not None:
            return CommandResult.refused(refusal)
        self.acquisition.dark_requested = True
        return CommandResult()

    def _publish_maps(self, command: PublishMapsCommand) -> CommandResult:
        self.request_maps()
        return CommandResult()

    def _record(self, command: RecordCommand) -> CommandResult:
        if self.recorder is None:
            return CommandResult.refused("nothing records: the configuration has no [recording] table")
        self.recorder.request_clip(command.seconds)
        return CommandResult()

    @property
    def frame_shape(self) -> tuple[int, int] | None:
        """The camera's frame (rows, columns): its word before frames flow, then the first frame's."""
        return self.measurement.frame_shape

    def apply(self, config: DaemonConfig, cadence: Cadence, recorder: Recorder | None) -> None:
        """A reload that keeps the measurement (``edgedsm.daemon.reload``): the new thresholds go
        to the running state machines (their states, dwell and trend history kept), the new
        cadence to the running loop, the recorder (the same one, or one rebuilt) gets the frames."""
        self.evaluator.apply(config)
        self.recorder = recorder
        self.cadence.stats_every_s = cadence.stats_every_s
        self.cadence.maps_every_s = cadence.maps_every_s
        self.config = self.measurement.config = config

    def restart(self, why: str, states: bool = True) -> None:
        """Empty the estimator window; with ``states``, every region goes back to warming up,
        announced as one ``reset`` alert."""
        self.measurement.restart()
        if states:
            self.evaluator.restart_states(why)
        else:
            log.info("measurement restarted (%s)", why)

    def publish_alert(self, alert: Alert) -> None:
        """Hand an alert to the sinks, in order with the evaluations (any thread)."""
        self.evaluator.publish_alert(alert)

    def request_maps(self) -> None:
        """Publish the maps at the next evaluation, whatever the cadence (pipeline thread)."""
        self._last_maps_t = float("-inf")

    # -- frames -------------------------------------------------------------------------------------
    def _take(self, timeout_s: float) -> Frame | None:
        frame = self.capture.take(timeout_s)
        if frame is None:
            return None
        if not self.measurement.settled:  # the first frame decides, before the laser goes on
            self.measurement.prepare(frame.format)
        self._last_frame_t = self.clock.monotonic()
        self.counters["frames"] += 1
        self._frames_t.append(self._last_frame_t)
        if len(self._frames_t) > FPS_FRAMES:
            del self._frames_t[:-FPS_FRAMES]
        if self.recorder is not None:
            self.recorder.offer(frame, self.acquisition.laser if self.acquisition.relay is not None else "none")
        if self.probes.frame_taken is not None:
            self.probes.frame_taken(frame, self.counters["frames"])
        self.on_alive()  # here, not only in the loop: a long dark phase must not starve the watchdog
        return frame

    def _device_fault(self, reason: str) -> None:
        """A fault of the whole device (laser relay, camera): one alert, the stats at once."""
        self._urgent = True
        self.publish_alert(Alert(kind=AlertKind.FAULT, t=self.clock.wall(), reason=reason))

    def _push(self, frame: Frame) -> None:
        started = time.perf_counter()
        if not self.measurement.push(frame, self.acquisition.dark):
            return
        if self.probes.frame_pushed is not None:
            self.probes.frame_pushed(frame, time.monotonic(), time.perf_counter() - started)
        if self.counters["frames"] % 16 == 0:
            # the lit level only weighs the ambient light (a warning at 10 %): 1/16 of the pixels will do
            self.lit_level = float(frame.pixels[::4, ::4].mean())

    def _fps(self) -> float:
        times = self._frames_t
        if len(times) < 2 or times[-1] <= times[0]:
            return 0.0
        return (len(times) - 1) / (times[-1] - times[0])

    # -- evaluation ---------------------------------------------------------------------------------
    def _evaluate(self, now: float, wait: bool = False, stats_due: bool = True) -> bool:
        """Hand a snapshot to the evaluator; False if skipped (the previous one still runs)."""
        if not self.evaluator.idle(wait):
            return False  # tried again at the next loop; the fault to report is kept for it
        fault = self._outage or self._fault
        self._fault = None
        status = Status(now=now, frames=self.counters["frames"], fps=self._fps(), laser=self.acquisition.laser,
                        drops={k: v for k, v in self.counters.items() if k.startswith("dropped")},
                        camera=dict(self.camera.stats), ambient_level=self.acquisition.ambient_level,
                        warning=self._ambient_warning(), fault=fault,
                        recording=self.recorder.stats() if self.recorder is not None else None)
        maps_due = now - self._last_maps_t >= self.cadence.maps_every_s
        snapshot = self.measurement.snapshot(status, maps_due, stats_due, self.evaluator.generation)
        self.evaluator.submit(snapshot, wait=wait)
        if snapshot.publish_maps:
            self._last_maps_t = now
        return True

    def _ambient_warning(self) -> str | None:
        ambient = self.acquisition.ambient_level
        if ambient is None or not self.lit_level:
            return None
        ratio = ambient / self.lit_level
        if ratio > AMBIENT_S2_WARNING and not self.config.estimator.ambient_correction:
            return (f"ambient light is {ratio:.0%} of the signal: plain S2 is unreliable (paper §2B); "
                    "use S3, which ambient light does not bias (docs/ambient.md)")
        return None

    def summary(self) -> str:
        """One line for systemd's STATUS: rate, frames, drops and the state of each region."""
        drops = sum(v for k, v in self.counters.items() if k.startswith("dropped"))
        return (f"{self._fps():.1f} frames/s, {self.counters['frames']} frames, {drops} dropped, "
                f"laser {self.acquisition.laser}; {self.evaluator.states_line()}")

    # -- main loop ----------------------------------------------------------------------------------
    def run(self, should_stop: Callable[[], bool], max_frames: int | None = None) -> None:
        """Measure until ``should_stop()`` is true (checked several times a second)."""
        acq, capture = self.acquisition, self.capture
        grab_timeout_s = self.config.camera.grab_timeout_s
        acq.switch_off("start")
        capture.open()
        try:
            hint = capture.frame_format()
            warm_up(self.config, hint.shape if hint else None)  # the kernels this size of frame runs
            if hint is not None:  # the engine built and written before frames flow (the first frame checks it)
                self.measurement.prepare(hint, frame=False)
        except BaseException:
            capture.stop(timeout_s=0.0)  # closes the camera
            raise
        capture.start()
        try:
            acq.take_dark_frames(self._take, grab_timeout_s)
            while not should_stop():
                self._handle_commands()
                if self.recorder is not None:
                    for reason in self.recorder.pending_faults():  # the disk refused: measuring goes on
                        self._device_fault(reason)
                now = self.clock.monotonic()
                if capture.error is not None:
                    raise capture.error
                camera_ok = self._camera_ok = self._watch_camera(now)
                if camera_ok and acq.dark_due(now):
                    acq.take_dark_frames(self._take, grab_timeout_s)
                laser = acq.laser
                acq.tick(now, camera_ok)
                self._urgent = self._urgent or acq.laser != laser
                frame = self._take(0.1)
                if frame is not None and acq.admit():
                    self._push(frame)
                if self._last_frame_t is not None and self.clock.monotonic() - self._last_frame_t < grab_timeout_s:
                    self.on_alive()
                cadence = self.cadence
                if now >= self._stats_due:
                    self._stats_due, self._stats_owed = next_due(self._stats_due, cadence.stats_every_s, now), True
                stats = self._urgent or (self._stats_owed and not self._frames_first(now))
                states_due = now >= self._states_due
                # skipped (the evaluator is busy): tried again at the next loop, nothing lost
                if (stats or states_due) and self._evaluate(now, stats_due=stats):
                    if stats:
                        self._urgent, self._stats_owed, self._last_stats_t = False, False, now
                    if states_due:  # an urgent evaluation in between leaves the grid alone
                        self._states_due = next_due(self._states_due, cadence.states_every_s, now)
                if max_frames is not None and self.counters["frames"] >= max_frames:
                    break
                if capture.ended:
                    if capture.error is not None:
                        raise capture.error
                    log.info("camera stream ended")
                    self.request_maps()  # the final maps go out whatever the cadence
                    self._evaluate(self.clock.monotonic(), wait=True)
                    break
        finally:
            capture.request_stop()  # joined below, once the laser is off
            acq.switch_off("stop")
            self.evaluator.finish()
            self.measurement.release()
            capture.stop(timeout_s=1.0)

    def _frames_first(self, now: float) -> bool:
        """Whether the statistics (and maps) owed wait: a paced camera's queue is at least
        ``POSTPONE_QUEUE_FILL`` full, and the last ones are less than ``POSTPONE_MAX_INTERVALS``
        stats intervals old. Their region pass and percentiles are most of an evaluation's cost;
        the drying states (their means only) are judged on their cadence meanwhile."""
        capture = self.capture
        backlog = self.camera.paced and capture.frames.qsize() >= POSTPONE_QUEUE_FILL * capture.capacity
        late = now - self._last_stats_t >= POSTPONE_MAX_INTERVALS * self.cadence.stats_every_s
        if backlog and not late:
            if not self._postponing:
                self._postponing = True
                self.counters["stats_postponed"] += 1
                level = logging.DEBUG  # a warning once a minute at most: a queue hovering at the mark
                if now - self._postpone_logged_t >= 60.0:  # would flood the journal
                    level, self._postpone_logged_t = logging.WARNING, now
                log.log(level, "frame queue %d of %d: statistics and maps wait (up to %.0f s) until it drains; "
                        "drying states go on (%d times so far)", capture.frames.qsize(), capture.capacity,
                        POSTPONE_MAX_INTERVALS * self.cadence.stats_every_s, self.counters["stats_postponed"])
            return True
        if self._postponing and not backlog:
            self._postponing = False
            log.debug("frame queue drained: statistics resume")
        return False

    def _watch_camera(self, now: float) -> bool:
        """Whether the camera is up. Down (lost, or silent for ``grab_timeout_s``): the laser goes
        off and one fault is reported per outage; up again once frames flowed ``CAMERA_STABLE_S``.
        Before its first frame it is not up either (the laser waits), but not yet a fault: the
        driver's own grab timeout tells a camera that never delivers."""
        capture, last = self.capture, self._last_frame_t
        silent = last is not None and now - last >= self.config.camera.grab_timeout_s
        lost_again = self.counters["camera_lost"] != self._losses_seen
        self._losses_seen = self.counters["camera_lost"]
        if capture.lost.is_set() or silent or lost_again:
            if self._outage is None:
                why = f"no frame for {now - last:.1f} s" if silent and last is not None else capture.loss_reason
                self._outage = "camera lost"
                self._device_fault(f"camera lost: {why}")
            self._back_since = None
            return False
        if last is None:
            return False
        if self._outage is None:
            return True
        if self._back_since is None:
            self._back_since = now
        if now - self._back_since < CAMERA_STABLE_S:
            return False
        log.warning("camera back: frames flowed for %.1f s", now - self._back_since)
        self._outage, self._back_since = None, None
        self.restart("camera back", states=False)  # the fault covered it
        return True
