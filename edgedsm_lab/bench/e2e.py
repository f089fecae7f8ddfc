"""End-to-end daemon benchmark: replayed frames → the daemon's own ``Pipeline`` → real mosquitto.

What runs is the daemon's code in this process, unmodified and watched only through its public
probes (``PipelineProbes``): the replay camera driver on a recorded ``.npy`` stack, ``Pipeline``
(capture thread, bounded drop-oldest queue sized by time, streaming engine with N = 200, m = 10
and all three maps, region statistics from the engine's sums between two pushes, evaluator
thread: percentiles, maps from a copy of the sums, drying states) and the MQTT sink
(``MqttSink``) talking to a private mosquitto (``LocalBroker``) on loopback. The recording is
simulated speckle (the constant-activity scene at 256², τc = 20 frames) tiled to ``--size``,
each tile shifted in time, in ``--pixel-format`` (Mono12p and Mono16 are replayed unpacked, as
uint16: the unpacking a real camera's frames need is timed on its own), played in a loop. The
default configuration is the issue's: stats every 1 s, maps every 10 s, drying states every 0.5
s, two large regions, the default queue (``acquisition.queue_seconds`` = 1 s). Every trial
measures for its seconds after the window filled (when evaluations start); drops are counted
over the whole trial.

Measured, in one run, per size:

1. **Bare engine**: ``SlidingWindow.push`` alone on the same frames (the upper bound), before
   the first trial and after each: the machine's speed drifts, so each trial is compared with
   the faster of the bare runs around it (the mean would flatter the daemon).
2. **Capacity**: the replay at rate 0 is a source that can wait; the pipeline holds it back when
   its queue is full, so frames/s is what the daemon processes at most.
3. **Capacity interleaved with the bare engine**, drift-free: one capacity trial in which the
   pipeline thread is held between two frames (through its ``frame_taken`` probe) while the bare
   engine, a second engine filled beforehand, pushes the same frames; phases of
   ``PHASE_S`` alternate daemon / bare / bare / daemon ..., and each pair's ratio is taken
   (their median is reported): the machine's drift over minutes cancels, which ratios to runs
   before and after a 20 s trial only bound.
4. **Highest paced rate with zero drops** on the default queue: the replay paced into the
   daemon's drop-oldest queue; bisection from 90 % of the bare engine's rate. Capacity and paced
   rates are given as ratios to the bare engine around each trial. The daemon postpones its
   statistics while the queue is half full (frames first): each trial gives the stats messages
   per second it published and how often they waited.
5. **Latency**: from a frame entering the queue to the drying states that include it being
   judged and their alerts handed to the sink (frame → alert), and to the stats message that
   counts it (frame → stats), p50 and p99, frames after the window filled.
6. **Cost that follows the regions** (``estimator.area = "regions"``): capacity with one
   region covering a decreasing fraction of the sensor, as ms per frame.

Examples:
  edgedsm bench e2e --quick                              # 2048² Mono8, about 3 minutes
  edgedsm bench e2e --size 2048x2048,4096x2168 -o docs/bench-e2e.md
  edgedsm bench e2e --size 1024x1024 --pixel-format Mono12p
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import itertools
import logging
import math
import statistics
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from edgedsm.config import DaemonConfig
from edgedsm.daemon.devices import open_camera_for
from edgedsm.daemon.handover import Snapshot
from edgedsm.daemon.pipeline import Cadence, Pipeline
from edgedsm.daemon.probes import PipelineProbes
from edgedsm.daemon.recording import Recorder
from edgedsm.estimators import SlidingWindow
from edgedsm.frames import Frame
from edgedsm.messages import Stats
from edgedsm.resources import data_file

HELP = "the daemon end to end (replay → pipeline → MQTT): bare engine vs daemon, zero-drop rate, latency"

TILE = 256
WINDOW, LAG = 200, 10
STATS_S, MAPS_S = 1.0, 10.0
RECORDED_FRAMES = 240
BARE_RUN_S = 6.0  # the bare engine's run after each trial (plus filling its window)
#: Interleaved capacity: seconds per phase (below the bench config's camera.grab_timeout_s, so
#: that a held pipeline is not a camera outage), the pause before a bare phase (the evaluation in
#: flight ends) and the daemon's seconds at capacity before the first phase.
PHASE_S, SETTLE_S, SETTLE_FIRST_S = 3.0, 0.3, 3.0
PHASE_PAIRS = 8  # daemon/bare pairs (quick: half)
FILL_LIMIT_S = 120.0  # a trial gives up when the window has not filled in this (plus its seconds)
PIXEL_FORMATS = {"Mono8": 8, "Mono12p": 12, "Mono16": 16}
COVERED = (1.0, 0.25, 0.0625, 0.01)  # fractions of the sensor the one region covers (area trials)
SCENE = data_file("config/scenes/constant.toml")


def parse_size(text: str) -> tuple[int, int]:
    """'WxH' → (height, width)."""
    try:
        width, height = (int(part) for part in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size must be WxH, e.g. 2048x2048, not {text!r}") from None
    if not (64 <= width <= 16384 and 64 <= height <= 16384):
        raise argparse.ArgumentTypeError(f"size {text}: width and height must be 64..16384")
    return height, width


# -- the recording -------------------------------------------------------------------------

def make_recording(path: Path, shape: tuple[int, int], bits: int = 8, frames: int = RECORDED_FRAMES) -> Path:
    """Simulated speckle (constant activity, τc = 20) at TILE², tiled to ``shape`` with each tile
    shifted in time, as a .npy stack (uint8 for 8 bits, else uint16 scaled to ``bits``)."""
    from edgedsm.sim import load_scene, simulate

    scene = load_scene(SCENE)
    scene.scene.size = TILE
    scene.scene.frames = frames
    small = np.stack(list(itertools.islice(simulate(scene), frames)))
    if bits > 8:  # the 8-bit speckle scaled to the full range, low bits from the high ones
        wide = small.astype(np.uint16)
        small = (wide << (bits - 8)) | (wide >> (16 - bits))
    stack = np.lib.format.open_memmap(path, mode="w+", dtype=small.dtype, shape=(frames, *shape))
    rows, cols = -(-shape[0] // TILE), -(-shape[1] // TILE)
    for t in range(frames):
        for k in range(rows * cols):
            row, col = divmod(k, cols)
            block = stack[t, row * TILE:(row + 1) * TILE, col * TILE:(col + 1) * TILE]
            block[...] = small[(t + 37 * k) % frames][:block.shape[0], :block.shape[1]]
    stack.flush()
    del stack
    return path


def filled_engine(recording: Path, bits: int) -> tuple[SlidingWindow, np.ndarray]:
    """The bare engine (the daemon's N, m and q) with its window filled from the recording, and the
    recording's frames (memory-mapped)."""
    stack = np.load(recording, mmap_mode="r")
    engine = SlidingWindow(stack.shape[1:], window=WINDOW, lag=LAG, q=1.0, bits=bits)
    for i in range(WINDOW):
        engine.push(stack[i % len(stack)])
    return engine, stack


def bare_engine(recording: Path, seconds: float, bits: int) -> float:
    """Frames/s of ``SlidingWindow.push`` alone on the recording's frames (after the window filled)."""
    engine, stack = filled_engine(recording, bits)
    count, started = 0, time.perf_counter()
    while time.perf_counter() - started < seconds:
        engine.push(stack[count % len(stack)])
        count += 1
    return count / (time.perf_counter() - started)


def unpack_ms(shape: tuple[int, int], pixel_format: str, repeats: int = 20) -> float:
    """ms to unpack one frame of ``pixel_format`` as a real camera's frames are (0 for Mono8)."""
    from edgedsm.devices.camera.pixels import decode_image, image_size

    if pixel_format == "Mono8":
        return 0.0
    raw = np.random.default_rng(0).integers(0, 256, image_size(pixel_format, shape[1], shape[0]), np.uint8)
    started = time.perf_counter()
    for _ in range(repeats):
        decode_image(raw, pixel_format, shape[1], shape[0])
    return 1e3 * (time.perf_counter() - started) / repeats


# -- instrumentation -----------------------------------------------------------------------

class Instruments:
    """Timestamps from the real pipeline's probes: each frame's entry into the queue and its
    push, the pipeline thread's cost of each push and of each evaluation's region statistics,
    each evaluation's cost on the evaluator thread and when its states (and alerts) and its
    stats were handed to the sink."""

    def __init__(self) -> None:
        self.enqueued: dict[int, float] = {}
        self.dequeued: list[int] = []  # seq in dequeue order: index i-1 is the i-th frame counted
        self.taken_t: list[float] = []  # when each was taken (monotonic)
        self.push_s: list[float] = []
        self.snapshot_s: list[float] = []
        self.evaluate_s: list[float] = []
        self.states: list[tuple[int, float]] = []  # (frames included, monotonic) per evaluation
        self.stats: list[tuple[int, float]] = []  # the same, stats messages only
        self.ready_at: int | None = None  # frames counted when the window filled
        self.ready_t: float | None = None  # and when (monotonic)
        self.rss_mib = 0.0  # the largest anonymous resident memory seen at an evaluation

    def probes(self) -> PipelineProbes:
        return PipelineProbes(frame_queued=lambda frame, t: self.enqueued.__setitem__(frame.seq, t),
                              frame_taken=self._taken,
                              frame_pushed=self._pushed, snapshot_taken=self._snapshot,
                              evaluated=self._evaluated, states_evaluated=lambda n, t: self.states.append((n, t)))

    def _taken(self, frame: Frame, count: int) -> None:
        self.dequeued.append(frame.seq)
        self.taken_t.append(time.monotonic())

    def stall_s(self, since: float) -> float:
        """The longest gap between two frames taken off the queue after ``since``: the
        pipeline thread's worst stall when frames were waiting (what the queue must cover)."""
        times = np.asarray([t for t in self.taken_t if t >= since])
        return float(np.diff(times).max()) if times.size > 1 else float("nan")

    def _pushed(self, frame: Frame, t: float, cost: float) -> None:
        self.push_s.append(cost)
        if len(self.push_s) == WINDOW:
            self.ready_at, self.ready_t = len(self.dequeued), t

    def _snapshot(self, snapshot: Snapshot, cost: float) -> None:
        if snapshot.ready:
            self.snapshot_s.append(cost)

    def _evaluated(self, stats: Stats, seconds: float) -> None:
        self.stats.append((stats.frames, time.monotonic()))
        self.rss_mib = max(self.rss_mib, anon_mib())  # while the engine's window is allocated
        if stats.ready:
            self.evaluate_s.append(seconds)


def latency(instruments: Instruments, handed: list[tuple[int, float]]) -> tuple[float, float]:
    """p50, p99 (s) from a frame entering the queue to the first hand-over in ``handed``
    ((frames included, when), in order) that includes it; frames after the window filled."""
    first = (instruments.ready_at or WINDOW) + 1
    waits: list[float] = []
    index = first
    for frames, t in handed:
        while index <= frames and index <= len(instruments.dequeued):
            entered = instruments.enqueued.get(instruments.dequeued[index - 1])
            if entered is not None:
                waits.append(t - entered)
            index += 1
    if not waits:
        return float("nan"), float("nan")
    p50, p99 = np.percentile(np.asarray(waits), [50, 99])
    return float(p50), float(p99)


# -- one trial -----------------------------------------------------------------------------

@dataclass
class Trial:
    label: str
    rate: float | None  # requested frames/s; None = capacity (back-pressure)
    queue_frames: int  # the queue's length at the end (sized by time)
    stats_s: float
    seconds: float
    delivered: int
    processed: int
    drops: int
    cpu_s: float
    rss: float  # anonymous resident MiB, the most seen at an evaluation
    latency: dict[str, tuple[float, float]] = field(default_factory=dict)  # "alert"/"stats" -> (p50, p99) s
    push_ms: tuple[float, float] = (float("nan"), float("nan"))  # mean, p99
    snapshot_ms: tuple[float, float] = (float("nan"), float("nan"))  # mean, max: on the pipeline thread
    evaluate_ms: tuple[float, float] = (float("nan"), float("nan"))  # mean, max: on the evaluator thread
    covered: float = 1.0  # fraction of the sensor the engine sees
    states_hz: float = float("nan")  # drying-state evaluations per second after the window filled
    stats_hz: float = float("nan")  # stats messages per second after the window filled
    postponed: int = 0  # times the statistics waited for a half-full queue (frames first)
    stall_s: float = float("nan")  # the pipeline thread's longest gap between two frames taken
    bare_fps: float = float("nan")  # the bare engine around this trial: the faster of the runs just before and after

    @property
    def judged_fps(self) -> float:
        """What the trial is judged on: frames/s processed (capacity) or requested (paced)."""
        return self.fps if self.rate is None else self.rate

    @property
    def bare_ratio(self) -> float:
        """``judged_fps`` ÷ the bare engine around the trial."""
        return self.judged_fps / self.bare_fps

    @property
    def fps(self) -> float:
        return self.processed / self.seconds

    @property
    def delivered_fps(self) -> float:
        return self.delivered / self.seconds

    @property
    def sustained(self) -> bool:
        """Paced, nothing dropped, and both the source and the daemon kept the requested pace
        (within 3 %): a daemon processing less than it is given only fills its queue, and drops once
        the queue is full, after the trial perhaps."""
        return (self.rate is not None and self.drops == 0 and self.delivered_fps >= 0.97 * self.rate
                and self.fps >= 0.97 * self.rate)

    @property
    def cpu_ms(self) -> float:
        return 1e3 * self.cpu_s / max(self.processed, 1)


def daemon_config(recording: Path, port: int, state_dir: Path, rate: float, bits: int,
                  shape: tuple[int, int], covered: float | None = None) -> DaemonConfig:
    """The default daemon configuration on the replay: two large regions (the whole sensor and
    its centre quarter), or with ``covered`` one centred region of that fraction and
    ``estimator.area = "regions"``."""
    height, width = shape
    thresholds = {"wet_above": 0.9, "dry_below": 0.5, "min_dwell_s": 1.0}
    if covered is None:
        regions = [{"name": "full", **thresholds},
                   {"name": "centre", "shape": "rect", "x": width // 4, "y": height // 4, "width": width // 2,
                    "height": height // 2, **thresholds}]
    else:
        w, h = max(8, round(width * covered**0.5)), max(8, round(height * covered**0.5))
        regions = [{"name": "panel", "shape": "rect", "x": (width - w) // 2, "y": (height - h) // 2, "width": w,
                    "height": h, **thresholds}]
    return DaemonConfig.model_validate({
        "device": {"name": "bench", "state_dir": str(state_dir)},
        "camera": {"uri": f"replay:{recording}?rate={rate:g}&loop=true&bits={bits}", "grab_timeout_s": 5.0},
        "acquisition": {"dark_frames": 0},
        "estimator": {"activity": "s2", "window": WINDOW, "lag": LAG, "q": 1.0,
                      "area": "frame" if covered is None else "regions"},
        "regions": regions,
        "mqtt": {"host": "127.0.0.1", "port": port},
        "cadence": {"stats_interval_s": STATS_S, "maps_interval_s": MAPS_S},
    })


def anon_mib() -> float:
    """This process's anonymous resident memory (MiB; Linux), what the daemon allocated."""
    with open("/proc/self/status", encoding="ascii") as status:
        for line in status:
            if line.startswith("RssAnon:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def run_trial(label: str, config: DaemonConfig, *, rate: float | None, seconds: float, covered: float = 1.0,
              wrap: Callable[[PipelineProbes], PipelineProbes] | None = None,
              recorder: Recorder | None = None) -> Trial:
    """Run the pipeline on ``config`` for ``seconds`` after its window filled and measure over
    those seconds (module docstring). ``wrap``: probes around the instruments' (the interleaved
    capacity holds the pipeline thread in one); ``recorder``: the pipeline's ``[recording]``."""
    from edgedsm.publish.json_sink import MqttSink

    assert config.mqtt is not None
    gc.collect()  # the previous trial's pipeline and camera (with its mapping of the recording) gone
    mqtt = MqttSink(config.mqtt, config.device.state_dir).start()
    instruments = Instruments()
    try:
        mqtt.wait_connected(10)
        camera = open_camera_for(config)
        probes = instruments.probes()
        pipeline = Pipeline(config, camera, mqtt, cadence=Cadence(STATS_S, MAPS_S),
                            probes=wrap(probes) if wrap else probes, recorder=recorder)
        # CPU time when the window filled; time and CPU time when the trial's seconds were up
        # (stopping is not measured)
        marks: dict[str, float] = {}
        started = time.monotonic()

        def should_stop() -> bool:
            now, ready_t = time.monotonic(), instruments.ready_t
            if ready_t is not None:
                marks.setdefault("cpu_ready", time.process_time())
            stop = (ready_t is not None and now - ready_t >= seconds) or now - started >= seconds + FILL_LIMIT_S
            if stop and "stop" not in marks:
                marks.update(stop=now, cpu_stop=time.process_time())
            return stop

        pipeline.run(should_stop)
        cpu_s = marks.get("cpu_stop", time.process_time()) - marks.get("cpu_ready", 0.0)
        rss = instruments.rss_mib or anon_mib()
    finally:
        mqtt.close(1.0)
    ready_t, ready_at = instruments.ready_t or started, instruments.ready_at or 0
    # measured up to the stop request: the shutdown's waits would understate every rate
    end_t = marks.get("stop", time.monotonic())
    wall = end_t - ready_t

    def within(t: float) -> bool:
        return ready_t <= t <= end_t

    delivered = sum(1 for t in instruments.enqueued.values() if within(t))
    trial = Trial(label, rate, pipeline.capture.capacity, STATS_S, wall, delivered,
                  pipeline.counters["frames"] - ready_at, pipeline.counters["dropped_queue"], cpu_s, rss,
                  covered=covered, stall_s=instruments.stall_s(ready_t))
    trial.states_hz = cadence_hz([t for _, t in instruments.states if within(t)])
    trial.stats_hz = cadence_hz([t for _, t in instruments.stats if within(t)])
    trial.postponed = pipeline.counters["stats_postponed"]
    trial.latency = {"alert": latency(instruments, instruments.states),
                     "stats": latency(instruments, instruments.stats)}
    if instruments.push_s:
        push = np.asarray(instruments.push_s[WINDOW:] or instruments.push_s)
        trial.push_ms = (1e3 * float(push.mean()), 1e3 * float(np.percentile(push, 99)))
    if instruments.snapshot_s:
        trial.snapshot_ms = (1e3 * statistics.fmean(instruments.snapshot_s), 1e3 * max(instruments.snapshot_s))
    if instruments.evaluate_s:
        trial.evaluate_ms = (1e3 * statistics.fmean(instruments.evaluate_s), 1e3 * max(instruments.evaluate_s))
    return trial


def cadence_hz(times: list[float]) -> float:
    """Events per second from the intervals between the first and the last of ``times`` (in
    order): a count over the trial's seconds would be one event off depending on the grid's
    phase (±0.05/s for states every 0.5 s over 20 s); nan with fewer than two."""
    if len(times) < 2 or times[-1] <= times[0]:
        return float("nan")
    return (len(times) - 1) / (times[-1] - times[0])


@dataclass
class Interleaved:
    """Frames/s of the daemon at its capacity and of the bare engine in alternating phases of one
    trial (daemon/bare, bare/daemon, ...): pair k is ``daemon[k]`` and ``bare[k]``."""

    daemon: list[float]
    bare: list[float]
    drops: int = 0

    @property
    def ratios(self) -> list[float]:
        return [d / b for d, b in zip(self.daemon, self.bare, strict=False)]

    @property
    def ratio(self) -> float:
        """The median of the pairs' ratios (nan without a pair)."""
        return statistics.median(self.ratios) if self.ratios else float("nan")


class Alternation:
    """Holds the pipeline thread between two frames while the bare engine runs, and counts the frames
    it takes: the probe wrapper and the phases of :func:`interleaved_capacity`."""

    def __init__(self, bare: Callable[[], None], pairs: int) -> None:
        self.bare_push = bare
        self.pairs = pairs
        self.running = threading.Event()
        self.running.set()
        self.taken = 0
        self.result = Interleaved([], [])

    def wrap(self, probes: PipelineProbes) -> PipelineProbes:
        inner = probes.frame_taken

        def taken(frame: Frame, count: int) -> None:
            self.running.wait()  # the pipeline thread waits here during a bare phase
            self.taken += 1
            if inner is not None:
                inner(frame, count)

        probes.frame_taken = taken
        return probes

    def phases(self, stop: threading.Event) -> None:
        """Once the daemon's window filled: ABBA phases (run on a thread of its own)."""
        while self.taken < WINDOW and not stop.wait(0.1):
            pass
        if stop.wait(SETTLE_FIRST_S):
            return
        for phase in range(2 * self.pairs):
            bare_now = phase % 2 != (phase // 2) % 2  # daemon, bare, bare, daemon, daemon, bare ...
            if stop.is_set():
                return
            if bare_now:
                self.running.clear()
                try:  # whatever happens here, the pipeline thread is let go (the trial ends)
                    time.sleep(SETTLE_S)
                    count, started = 0, time.monotonic()
                    while time.monotonic() - started < PHASE_S:
                        self.bare_push()
                        count += 1
                    self.result.bare.append(count / (time.monotonic() - started))
                finally:
                    self.running.set()
            else:
                taken, started = self.taken, time.monotonic()
                time.sleep(PHASE_S)
                self.result.daemon.append((self.taken - taken) / (time.monotonic() - started))


def interleaved_capacity(recording: Path, config: DaemonConfig, bits: int, pairs: int) -> Interleaved:
    """The daemon at its capacity and the bare engine in alternating phases of one trial (see the
    module docstring); the bare engine's window is filled before the trial."""
    engine, stack = filled_engine(recording, bits)
    frames = itertools.count(WINDOW)  # on from where the filling stopped
    alternation = Alternation(lambda: engine.push(stack[next(frames) % len(stack)]), pairs)
    stop = threading.Event()
    thread = threading.Thread(target=alternation.phases, args=(stop,), name="bench-phases", daemon=True)
    thread.start()
    # the phases' own overshoot (a bare push past the phase's end, the wait for the window) is a
    # fraction of a second per phase: the trial runs on well past them
    seconds = SETTLE_FIRST_S + pairs * (2 * PHASE_S + SETTLE_S) + 5.0
    try:
        trial = run_trial("interleaved", config, rate=None, seconds=seconds, wrap=alternation.wrap)
    finally:
        stop.set()
        alternation.running.set()
        thread.join(PHASE_S + 1.0)
    alternation.result.drops = trial.drops
    return alternation.result


def search_rate(run: Callable[[float], Trial], start: float, ceiling: float, max_trials: int,
                resolution: float = 10.0, step: float = 5.0) -> list[Trial]:
    """Paced trials bisecting between the highest rate known to be sustained (0 at first) and the
    lowest known not to be (``ceiling`` at first), starting at ``start``, on multiples of ``step``
    frames/s, until the bracket is ``resolution`` wide or ``max_trials`` ran; the trials in order.
    When the start fails, the next trial is 10 % lower (the machine's drift alone can fail a
    start at the target) before bisecting down from there."""
    trials: list[Trial] = []
    low, high = 0.0, ceiling
    rate = start
    while len(trials) < max_trials:
        trial = run(rate)
        trials.append(trial)
        if trial.sustained:
            low = max(low, rate)
        else:
            high = min(high, rate)
        if high - low <= resolution:
            break
        if len(trials) == 1 and not trial.sustained:
            rate = step * math.floor(0.9 * rate / step)
        else:
            rate = step * round((low + high) / (2.0 * step))
        if not low < rate < high:
            break
    return trials


def best_zero_drop(trials: list[Trial]) -> Trial | None:
    clean = [t for t in trials if t.sustained]
    return max(clean, key=lambda t: t.rate or 0.0) if clean else None


@dataclass
class SizeResult:
    """Everything measured at one frame size, in one run."""

    shape: tuple[int, int]
    pixel_format: str
    bare_runs: list[float]  # frames/s of every bare-engine run, in order (one before the first trial, one after each)
    unpack_ms: float
    capacity: Trial
    paced: list[Trial]
    areas: list[Trial]
    interleaved: Interleaved | None = None

    @property
    def best(self) -> Trial | None:
        return best_zero_drop(self.paced)

    @property
    def bare_fps(self) -> float:
        """The bare engine's rate over the run (median of its runs)."""
        return statistics.median(self.bare_runs)


@contextlib.contextmanager
def quiet_daemon_logs() -> Iterator[None]:
    """The daemon's warnings (drying transitions) would interleave with the tables."""
    logger = logging.getLogger("edgedsm")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        yield
    finally:
        logger.setLevel(level)


def measure_size(shape: tuple[int, int], pixel_format: str, workdir: Path, port: int, *, seconds: float,
                 max_trials: int, areas: bool, say: Callable[[str], None], pairs: int = PHASE_PAIRS) -> SizeResult:
    bits = PIXEL_FORMATS[pixel_format]
    name = f"{shape[1]}x{shape[0]}"
    say(f"{name} {pixel_format}: recording {RECORDED_FRAMES} frames ...")
    recording = make_recording(workdir / f"{name}-{bits}.npy", shape, bits)
    trial_id = itertools.count()

    bare_runs: list[float] = []

    def bare(run_seconds: float) -> float:
        bare_runs.append(bare_engine(recording, run_seconds, bits))
        return bare_runs[-1]

    def trial(label: str, rate: float | None, covered: float | None = None) -> Trial:
        config = daemon_config(recording, port, workdir / f"state-{next(trial_id)}", rate or 0, bits, shape, covered)
        result = run_trial(label, config, rate=rate, seconds=seconds, covered=covered or 1.0)
        if covered is not None:  # the area trials compare with each other, not with the bare engine
            return result
        before = bare_runs[-1]
        # the machine's speed drifts: the engine around the trial, the faster run (never flattering)
        result.bare_fps = max(before, bare(BARE_RUN_S))
        say(f"  {label}: rate {result.rate or 'max'}, {result.fps:.1f} frames/s processed, {result.drops} dropped; "
            f"bare engine around it {result.bare_fps:.1f} frames/s")
        return result

    say(f"  bare engine, {seconds:g} s ...")
    say(f"  bare engine: {bare(seconds):.1f} frames/s")
    capacity = trial("capacity", None)
    say(f"  capacity interleaved with the bare engine, {pairs} pairs of {PHASE_S:g} s phases ...")
    interleaved = interleaved_capacity(recording, daemon_config(recording, port, workdir / f"state-{next(trial_id)}",
                                                                0, bits, shape), bits, pairs)
    say(f"  interleaved: daemon ÷ bare {', '.join(f'{r:.0%}' for r in interleaved.ratios)}; "
        f"median {interleaved.ratio:.0%}")
    # the first paced trial is at the target, 90 % of the bare engine's latest run rounded up (so
    # that passing it shows the target met), on a grid of at most 2 % of the rate (87 % and 90 %
    # told apart at any size), bisected down to adjacent grid points
    rate_now = bare_runs[-1]
    step = 5.0 if rate_now >= 250 else 1.0 if rate_now >= 50 else 0.5
    paced = search_rate(lambda rate: trial("paced", rate), start=step * max(1, math.ceil(0.9 * rate_now / step)),
                        ceiling=max(rate_now, capacity.fps) * 1.05, max_trials=max_trials, resolution=step,
                        step=step)
    covered = [trial(f"area, {100 * c:g} %", None, c) for c in COVERED] if areas else []
    recording.unlink()
    return SizeResult(shape, pixel_format, bare_runs, unpack_ms(shape, pixel_format), capacity,
                      sorted(paced, key=lambda t: t.rate or 0.0), covered, interleaved)

