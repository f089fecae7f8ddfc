"""The measurement pipeline: camera → bounded queue → streaming estimator → region statistics →
drying-state machine → publisher, with the laser switched as the acquisition plan says.

Threads: a capture thread pulls frames from the camera into a bounded queue (when the queue is
full the oldest frame is dropped and counted: a slow consumer never stalls the camera); the
thread that calls :meth:`Pipeline.run` does everything else, so estimator, state machine and
publisher need no locks. Commands (from MQTT) are queued to that thread too.

Laser safety: the laser is switched on only while frames are wanted, and off on camera loss,
during dark frames, between bursts, at stop and on any error (``run`` switches it off in a
``finally``; the service wraps the whole in ``LaserSafety``).
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import Counter
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import TimeoutError as FuturesTimeout
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from edgedsm.analysis import region_stats
from edgedsm.config import DaemonConfig
from edgedsm.devices.camera.base import Backoff, Camera
from edgedsm.devices.laser.base import LaserRelay
from edgedsm.drying import DryingMonitor, Transition
from edgedsm.errors import ConfigError, DeviceError, DeviceLost, DeviceTimeout, EdgedsmError, FrameError
from edgedsm.estimators import ESTIMATORS, SlidingWindow
from edgedsm.frames import Frame

log = logging.getLogger(__name__)

#: Plain S2 is judged unreliable (paper §2B) when the ambient level exceeds this fraction of
#: the mean lit level.
AMBIENT_S2_WARNING = 0.1
#: How long stopping waits for an evaluation in flight (s); well inside SIGTERM's 2 s.
EVALUATION_TIMEOUT_S = 1.0
#: Frames smaller than this are processed by one kernel thread (unless estimator.threads says).
SMALL_FRAME_PIXELS = 1 << 18


def available_memory() -> int | None:
    """Bytes the kernel says can be allocated without swapping (None if unknown)."""
    try:
        with open("/proc/meminfo") as handle:
            for line in handle:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        return None
    return None


def check_engine_memory(frame: Frame, window: int, mode: str) -> None:
    """Refuse, with the config key to change, a window whose ring cannot fit in memory."""
    if mode != "sliding":
        return  # tumbling and exponential keep m frames only
    needed = frame.pixels.size * (window * frame.pixels.itemsize + 40)
    free = available_memory()
    if free is not None and needed > 0.8 * free:
        raise ConfigError(f"estimator.window: a sliding window of {window} frames of {frame.shape[1]}x{frame.shape[0]} "
                          f"needs {needed / 2**30:.1f} GiB; this machine has {free / 2**30:.1f} GiB available "
                          "(use a shorter window, or mode = 'tumbling' or 'exponential')")


class Publisher(Protocol):
    """What the pipeline needs from a publisher (MQTT, or a recorder in tests)."""

    def publish_state(self, state: dict[str, Any]) -> None: ...

    def publish_alert(self, alert: dict[str, Any]) -> None: ...

    def publish_stats(self, stats: dict[str, Any]) -> None: ...

    def publish_map(self, name: str, values: np.ndarray, meta: dict[str, Any]) -> None: ...


@dataclass
class Cadence:
    """How often the pipeline evaluates and publishes (seconds of pipeline clock)."""

    stats_every_s: float = 1.0
    maps_every_s: float = 10.0


@dataclass
class _Capture:
    """Shared between the capture thread and the pipeline thread."""

    frames: queue.Queue[Frame] = field(default_factory=lambda: queue.Queue())
    lost: threading.Event = field(default_factory=threading.Event)
    error: BaseException | None = None
    stop: threading.Event = field(default_factory=threading.Event)


class Pipeline:
    """One camera's measurement loop (see the module docstring)."""

    def __init__(self, config: DaemonConfig, camera: Camera, publisher: Publisher,
                 relay: LaserRelay | None = None, cadence: Cadence | None = None,
                 clock: Callable[[], float] = time.monotonic, wall: Callable[[], float] = time.time,
                 on_alive: Callable[[], None] | None = None) -> None:
        self.config = config
        self.camera = camera
        self.publisher = publisher
        self.relay = relay
        self.cadence = cadence or Cadence()
        self.clock = clock
        self.wall = wall
        self.on_alive = on_alive or (lambda: None)
        self.counters: Counter[str] = Counter()
        self.monitor = DryingMonitor({r.name: r.thresholds() for r in config.regions}, t0=clock())
        self.engine: SlidingWindow | None = None
        self.masks: dict[str, np.ndarray] = {}
        self.dark: np.ndarray | None = None
        self.ambient_level: float | None = None
        self.lit_level: float | None = None
        self.laser_on = False
        self.manual_laser: bool | None = None
        self._commands: queue.Queue[tuple[str, dict, Future]] = queue.Queue()
        self._capture = _Capture(frames=queue.Queue(maxsize=config.acquisition.queue_frames))
        self._thread: threading.Thread | None = None
        self._last_frame_t = clock()
        self._last_dark_t = -np.inf
        self._last_stats_t = -np.inf
        self._last_maps_t = -np.inf
        self._frames_t: list[float] = []
        self._state_published: dict | None = None
        self._relight = False  # the camera came back: restart measuring once
        self._losses_seen = 0
        self._fault: str | None = None  # reported at the next evaluation, then cleared
        self._burst_started = -np.inf  # bursts mode: when the current burst began
        self._burst_frames = 0
        self._evaluator = ThreadPoolExecutor(max_workers=1, thread_name_prefix="edgedsm-evaluate")
        self._pending: Future | None = None
        self._monitor_lock = threading.Lock()  # the evaluator steps the monitor, commands reset it

    # -- laser ------------------------------------------------------------------------------
    def _set_laser(self, on: bool, why: str) -> None:
        if self.manual_laser is not None:
            on = on and self.manual_laser
        if self.relay is None:
            self.laser_on = on
            return
        if on == self.laser_on and on:
            return
        try:
            (self.relay.on if on else self.relay.off)()
            self.laser_on = on
            log.info("laser %s (%s)", "on" if on else "off", why)
        except DeviceError as exc:
            self.counters["laser_errors"] += 1
            self.laser_on = False
            raise DeviceError(f"laser relay failed while switching {'on' if on else 'off'} ({why}): {exc}") from exc

    def _laser_off_quietly(self, why: str) -> None:
        try:
            self._set_laser(False, why)
        except DeviceError as exc:
            log.error("could not switch the laser off (%s): %s", why, exc)

    # -- capture thread ---------------------------------------------------------------------
    def _capture_loop(self) -> None:
        capture = self._capture
        cam = self.config.camera
        backoff = Backoff(initial=cam.reconnect_initial_s, maximum=cam.reconnect_max_s)
        while not capture.stop.is_set():
            try:
                for frame in self.camera.frames(timeout_s=cam.grab_timeout_s):
                    self._enqueue(frame)
                    if capture.stop.is_set():
                        return
                return  # a finite source (replay) ended
            except (DeviceLost, DeviceTimeout) as exc:
                log.warning("camera lost: %s", exc)
                capture.lost.set()
                self.counters["camera_lost"] += 1
                if not self._reopen(backoff):
                    return
            except BaseException as exc:  # handed to the pipeline thread, which stops
                capture.error = exc
                capture.lost.set()
                return

    def _reopen(self, backoff: Backoff) -> bool:
        self.camera.close()
        for delay in backoff.delays():
            if self._capture.stop.wait(delay):
                return False
            try:
                self.camera.open()
                self._apply_camera_settings()
            except DeviceError as exc:
                log.info("camera still unavailable: %s", exc)
                self.camera.close()
                continue
            self.counters["camera_reconnects"] += 1
            log.warning("camera reconnected")
            self._capture.lost.clear()
            return True
        return False

    def _enqueue(self, frame: Frame) -> None:
        frames = self._capture.frames
        if not self.camera.paced:
            # a source that can wait (replay as fast as possible) is held back, not dropped
            while not self._capture.stop.is_set():
                try:
                    frames.put(frame, timeout=0.1)
                    return
                except queue.Full:
                    continue
            return
        while True:
            try:
                frames.put_nowait(frame)
                return
            except queue.Full:
                try:
                    frames.get_nowait()
                    self.counters["dropped_queue"] += 1
                except queue.Empty:
                    pass

    def _apply_camera_settings(self) -> None:
        cam = self.config.camera
        if cam.pixel_format:
            self.camera.set_pixel_format(cam.pixel_format)
        if cam.exposure_us:
            self.camera.set_exposure(cam.exposure_us)
        if cam.frame_interval_s:
            self.camera.set_frame_interval(cam.frame_interval_s)

    # -- commands (called from other threads) -------------------------------------------------
    def submit(self, name: str, args: dict | None = None, timeout_s: float = 5.0) -> dict:
        """Run a command on the pipeline thread and wait (bounded) for its result."""
        future: Future = Future()
        self._commands.put((name, args or {}, future))
        try:
            return future.result(timeout=timeout_s)
        except TimeoutError:
            return {"ok": False, "error": f"command {name!r} not handled within {timeout_s} s"}

    def _handle_commands(self) -> None:
        while True:
            try:
                name, args, future = self._commands.get_nowait()
            except queue.Empty:
                return
            try:
                future.set_result(self._command(name, args))
            except EdgedsmError as exc:
                future.set_result({"ok": False, "error": str(exc)})
            except Exception as exc:  # a command must never take the measurement down
                log.exception("command %s failed", name)
                future.set_result({"ok": False, "error": f"internal error: {exc}"})

    def _command(self, name: str, args: dict) -> dict:
        if name == "laser":
            state = args.get("state")
            if state not in ("on", "off", "auto"):
                return {"ok": False, "error": "state must be 'on', 'off' or 'auto'"}
            self.manual_laser = None if state == "auto" else state == "on"
            self._set_laser(state != "off", f"command laser {state}")
            return {"ok": True, "laser": "on" if self.laser_on else "off"}
        if name == "rebaseline":
            self._reset_measurement("command rebaseline")
            return {"ok": True}
        if name == "dark":
            self._last_dark_t = -np.inf
            return {"ok": True}
        if name == "publish_maps":
            self._last_maps_t = -np.inf
            return {"ok": True}
        return {"ok": False, "error": f"unknown command {name!r}"}

    # -- measurement ----------------------------------------------------------------------------
    def _reset_measurement(self, why: str, states: bool = True) -> None:
        """Empty the estimator window; with ``states``, every region goes back to warming up."""
        if self.engine is not None:
            self.engine.reset()
        if states:
            with self._monitor_lock:
                for transition in self.monitor.reset(self.clock(), why):
                    self._alert(transition)
        log.info("measurement restarted (%s)", why)

    def _make_engine(self, frame: Frame) -> None:
        est = self.config.estimator
        threads = est.threads
        if threads is None and frame.pixels.size < SMALL_FRAME_PIXELS:
            # a parallel pass over a small frame costs more in thread wake-ups than it saves, and
            # stalls badly when the capture thread competes for the cores
            threads = 1
        check_engine_memory(frame, est.window, est.mode)
        self.engine = SlidingWindow(frame.shape, window=est.window, lag=est.lag, q=est.q, bits=frame.bits,
                                    estimators=ESTIMATORS, mode=est.mode, threads=threads)
        self.masks = {r.name: r.mask(frame.shape, self.config.base_dir) for r in self.config.regions}

    def _measuring(self, now: float) -> bool:
        """Whether frames are wanted now; in bursts mode this starts and ends bursts."""
        acq = self.config.acquisition
        if acq.mode == "continuous":
            return True
        if self._burst_started > -np.inf and self._burst_frames < acq.burst_frames:
            return True
        if now - self._burst_started >= acq.burst_period_s:
            self._burst_started, self._burst_frames = now, 0
            self._reset_measurement("burst start", states=False)  # states hold between bursts
            self._set_laser(True, "burst")
            self._drain()
            return True
        if self.laser_on:
            self._evaluate(now)  # the burst's final maps and states
            self._set_laser(False, "between bursts")
        return False

    def _next_frame(self, timeout_s: float) -> Frame | None:
        try:
            frame = self._capture.frames.get(timeout=timeout_s)
        except queue.Empty:
            return None
        self._last_frame_t = self.clock()
        self.counters["frames"] += 1
        self._frames_t.append(self._last_frame_t)
        if len(self._frames_t) > 64:
            del self._frames_t[:-64]
        return frame

    def _take_dark_frames(self) -> None:
        count = self.config.acquisition.dark_frames
        if count == 0 or self.relay is None:
            return
        self._set_laser(False, "dark frames")
        self._drain()
        frames = []
        deadline = self.clock() + self.config.camera.grab_timeout_s * (count + 2)
        while len(frames) < count + 1 and self.clock() < deadline and not self._capture.lost.is_set():
            frame = self._next_frame(0.5)
            if frame is not None:
                frames.append(frame.pixels)
        # the first frame may have been exposed while the relay was still switching
        if len(frames) > 1:
            stack = np.stack(frames[1:]).astype(np.float64)
            self.dark = np.rint(stack.mean(axis=0)).astype(frames[0].dtype)
            self.ambient_level = float(stack.mean())
            log.info("ambient level %.2f grey from %d dark frames", self.ambient_level, len(frames) - 1)
        self._last_dark_t = self.clock()
        self._drain()

    def _drain(self) -> None:
        while True:
            try:
                self._capture.frames.get_nowait()
            except queue.Empty:
                return

    def _push(self, frame: Frame) -> None:
        if self.engine is None:  # the first frame fixes the shape; later misfits are refused
            self._make_engine(frame)
        pixels = frame.pixels
        if self.config.estimator.ambient_correction and self.dark is not None and self.dark.shape == pixels.shape:
            # ambient-corrected S2: the dark level is subtracted before normalising (saturating at 0)
            pixels = np.subtract(pixels, np.minimum(pixels, self.dark))
        try:
            assert self.engine is not None
            self.engine.push(pixels)
        except FrameError as exc:
            self.counters["dropped_invalid"] += 1
            log.warning("frame %d dropped: %s", frame.seq, exc)
            return
        if self.counters["frames"] % 16 == 0:
            self.lit_level = float(frame.pixels.mean())

    def _evaluate(self, now: float, wait: bool = False) -> None:
        """Snapshot the maps here, analyse and publish them on the evaluator thread.

        The pipeline thread only pays for ``engine.maps()``; region statistics, drying states
        and publishing run beside the next pushes. An evaluation that is due while the previous
        one still runs is skipped (counted); ``wait`` makes this one run to its end.
        """
        if self._pending is not None:
            if not self._pending.done() and not wait:
                self.counters["evaluations_skipped"] += 1
                return
            pending, self._pending = self._pending, None
            pending.result()  # re-raises an error of the evaluator thread here
        snapshot = self._snapshot(now)
        self._pending = self._evaluator.submit(self._analyse, snapshot)
        if wait:
            pending, self._pending = self._pending, None
            pending.result()

    def _snapshot(self, now: float) -> dict[str, Any]:
        engine = self.engine
        ready = engine is not None and engine.ready
        stats: dict[str, Any] = {"t": self.wall(), "frames": self.counters["frames"], "ready": ready,
                                 "fps": self._fps(), "laser": "on" if self.laser_on else "off",
                                 "drops": {k: v for k, v in self.counters.items() if k.startswith("dropped")},
                                 "camera": dict(self.camera.stats), "ambient_level": self.ambient_level,
                                 "estimator": self.config.estimator.activity, "regions": {}}
        warning = self._ambient_warning()
        if warning:
            stats["warning"] = warning
        fault = "camera lost" if self._capture.lost.is_set() else self._fault
        self._fault = None
        maps = engine.maps() if ready and engine is not None else {}  # fresh arrays: safe to hand over
        publish_maps = bool(maps) and now - self._last_maps_t >= self.cadence.maps_every_s
        if publish_maps:
            self._last_maps_t = now
        return {"now": now, "ready": ready, "fault": fault, "stats": stats, "maps": maps,
                "publish_maps": publish_maps}

    def _analyse(self, snapshot: dict[str, Any]) -> None:
        """Region statistics, drying states, publishing (evaluator thread)."""
        now, ready, fault, stats, maps = (snapshot[k] for k in ("now", "ready", "fault", "stats", "maps"))
        estimator = stats["estimator"]
        activities: dict[str, float] = {}
        for name, mask in self.masks.items() if maps else ():
            per_map = {key: region_stats(values, mask).as_dict() for key, values in maps.items()}
            stats["regions"][name] = per_map
            activities[name] = per_map[estimator]["mean"]
        with self._monitor_lock:
            transitions = self.monitor.step(now, activities, ready=ready and fault is None, fault=fault)
            for transition in transitions:
                self._alert(transition)
            state = {"t": self.wall(), "estimator": estimator, "regions": self.monitor.snapshot()}
        stats["state"] = {name: s["state"] for name, s in state["regions"].items()}
        self.publisher.publish_stats(stats)
        if transitions or self._state_published is None:
            self.publisher.publish_state(state)
            self._state_published = state
        if snapshot["publish_maps"]:
            est = self.config.estimator
            for name, values in maps.items():
                self.counters["maps_published"] += 1
                self.publisher.publish_map(name, values, {"estimator": name, "window": est.window,
                                                          "lag": est.lag, "frames": stats["frames"],
                                                          "t": stats["t"]})

    def _alert(self, transition: Transition) -> None:
        alert = transition.as_dict()
        alert["t"] = self.wall()
        log.warning("region %s: %s -> %s (%s)", transition.region, transition.from_state, transition.to_state,
                    transition.reason)
        self.publisher.publish_alert(alert)

    def _ambient_warning(self) -> str | None:
        if self.ambient_level is None or not self.lit_level:
            return None
        ratio = self.ambient_level / self.lit_level
        if ratio > AMBIENT_S2_WARNING and not self.config.estimator.ambient_correction:
            return (f"ambient light is {ratio:.0%} of the signal: plain S2 is unreliable (paper §2B); "
                    "use S3 or estimator.ambient_correction")
        return None

    def summary(self) -> str:
        """One line for systemd's STATUS: rate, frames, drops and the state of each region."""
        with self._monitor_lock:
            states = ", ".join(f"{name} {machine.state}" for name, machine in self.monitor.regions.items())
        drops = sum(v for k, v in self.counters.items() if k.startswith("dropped"))
        return (f"{self._fps():.1f} frames/s, {self.counters['frames']} frames, {drops} dropped, "
                f"laser {'on' if self.laser_on else 'off'}; {states}")

    def _fps(self) -> float:
        times = self._frames_t
        if len(times) < 2 or times[-1] <= times[0]:
            return 0.0
        return (len(times) - 1) / (times[-1] - times[0])

    # -- main loop --------------------------------------------------------------------------------
    def run(self, should_stop: Callable[[], bool], max_frames: int | None = None) -> None:
        """Measure until ``should_stop()`` is true (checked several times a second)."""
        acq = self.config.acquisition
        self._laser_off_quietly("start")
        self.camera.open()
        self._apply_camera_settings()
        self._thread = threading.Thread(target=self._capture_loop, name="edgedsm-capture", daemon=True)
        self._thread.start()
        try:
            self._take_dark_frames()
            self._set_laser(self._measuring(self.clock()), "measuring")
            while not should_stop():
                self._handle_commands()
                now = self.clock()
                if self._capture.error is not None:
                    raise self._capture.error
                if self._capture.lost.is_set() or self.counters["camera_lost"] != self._losses_seen:
                    # latched: a loss shorter than the stats interval is still reported as a fault
                    self._losses_seen = self.counters["camera_lost"]
                    self._fault = "camera lost"
                    if self.laser_on:
                        self._laser_off_quietly("camera lost")
                    self._relight = True
                if self._relight and not self._capture.lost.is_set():
                    self._relight = False
                    self._reset_measurement("camera reconnected", states=False)  # the fault covers it
                    self._set_laser(self._measuring(now), "camera back")
                if acq.dark_every_min > 0 and now - self._last_dark_t >= acq.dark_every_min * 60:
                    self._take_dark_frames()
                    self._set_laser(self._measuring(now), "after dark frames")
                frame = self._next_frame(0.1)
                if frame is not None and self._measuring(self.clock()):
                    self._push(frame)
                    self._burst_frames += 1
                if self.clock() - self._last_frame_t < self.config.camera.grab_timeout_s:
                    self.on_alive()
                if now - self._last_stats_t >= self.cadence.stats_every_s:
                    self._last_stats_t = now
                    self._evaluate(now)
                if max_frames is not None and self.counters["frames"] >= max_frames:
                    break
                if self._thread is not None and not self._thread.is_alive() and self._capture.frames.empty():
                    if self._capture.error is not None:
                        raise self._capture.error
                    log.info("camera stream ended")
                    self._last_maps_t = -np.inf  # the final maps go out whatever the cadence
                    self._evaluate(self.clock(), wait=True)
                    break
        finally:
            self._capture.stop.set()
            self._laser_off_quietly("stop")
            self._finish_evaluation()
            if self._thread is not None:
                self._thread.join(timeout=1.0)
            self.camera.close()

    def _finish_evaluation(self) -> None:
        """Let a running evaluation end (bounded), so its alerts and maps are not lost."""
        pending, self._pending = self._pending, None
        if pending is not None:
            try:
                pending.result(timeout=EVALUATION_TIMEOUT_S)
            except FuturesTimeout:
                log.warning("the last evaluation did not finish within %.1f s", EVALUATION_TIMEOUT_S)
            except Exception:
                log.exception("the last evaluation failed")
        self._evaluator.shutdown(wait=False)
