"""The end-to-end benchmark's trial: a recorded speckle stack, the daemon's own ``Pipeline`` fed
from it through the replay driver, watched through its probes (``Instruments``), and the bare
engine on the same frames; what one trial measured (``Trial``). The runs and tables that use it:
:mod:`edgedsm_lab.bench.e2e`."""

from __future__ import annotations

import argparse
import contextlib
import gc
import itertools
import logging
import queue
import statistics
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from edgedsm.config import CadenceSection, DaemonConfig
from edgedsm.daemon.devices import open_camera_for
from edgedsm.daemon.handover import Snapshot
from edgedsm.daemon.pipeline import Cadence, Pipeline
from edgedsm.daemon.probes import PipelineProbes
from edgedsm.daemon.recording import Recorder
from edgedsm.devices.camera import Camera
from edgedsm.devices.camera.replay import ReplayCamera
from edgedsm.estimators import SlidingWindow
from edgedsm.frameio import FrameReader
from edgedsm.frameio.npy import NpyReader
from edgedsm.frames import Frame
from edgedsm.messages import Stats
from edgedsm.resources import data_file

TILE = 256
WINDOW, LAG = 200, 10
STATS_S, MAPS_S = 1.0, 10.0
#: The benchmark's cadence (the issue's: statistics every second, maps every 10 s, drying states
#: twice a second), more often than the daemon's own.
BENCH = Cadence(STATS_S, MAPS_S)
#: The daemon's own cadence, a configuration without ``[cadence]`` (its defaults,
#: ``CadenceSection``): what a site runs unless it asks for more.
SHIPPED = Cadence.of(CadenceSection())
#: A cadence with no evaluation within a trial (the first, before the window filled, aside): the
#: daemon's cost per frame alone, beside which the evaluations' cost shows.
QUIET = Cadence(stats_every_s=3600.0, maps_every_s=3600.0, states_every_s=3600.0)
RECORDED_FRAMES = 240
FILL_LIMIT_S = 120.0  # a trial gives up when the window has not filled in this (plus its seconds)
SCENE = data_file("config/scenes/constant.toml")
#: Where the replay camera takes its frames: "file" reads each from the recording (one copy per
#: frame on the capture thread, as every camera's delivery costs), "memory" serves them from the
#: recording read once at open (no copy per frame: the daemon's own cost alone, the frames
#: reached as the bare engine reaches them).
SOURCES = ("file", "memory")


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


#: Recordings read into memory, by path: read once per run, before the trials (2.1 GB at
#: 4096×2168 took 32 s when the file had left the page cache), not at each trial's start.
_HELD: dict[Path, np.ndarray] = {}


def held_recording(path: Path) -> np.ndarray:
    """The recording at ``path`` as one read-only array, read on the first call."""
    if path not in _HELD:
        with NpyReader(path) as reader:
            held = reader.window(0, reader.count or 0)
        held.setflags(write=False)
        _HELD[path] = held
    return _HELD[path]


def forget_recording(path: Path) -> None:
    """Let the memory of :func:`held_recording` go (the run is done with ``path``)."""
    _HELD.pop(path, None)


class MemoryReader(NpyReader):
    """A .npy recording served from memory (:func:`held_recording`), each frame as it is (read-only)."""

    kind = "memory"

    def __init__(self, path: Path, channel: str | None = None) -> None:
        super().__init__(path, channel)
        self.held = held_recording(path)

    def _raw(self, start: int) -> Iterator[tuple[int, np.ndarray]]:
        for index in range(start, len(self.held)):
            yield index, self.held[index]


class MemoryReplay(ReplayCamera):
    """The replay camera over a :class:`MemoryReader`: frames delivered without a copy."""

    def _open_reader(self) -> FrameReader:
        return MemoryReader(self.path)


def open_source(config: DaemonConfig, source: str, recording: Path, rate: float, bits: int) -> Camera:
    """The trial's camera: the daemon's own replay of ``config`` ("file"), or the same recording
    served from memory ("memory")."""
    if source == "file":
        return open_camera_for(config)
    if source == "memory":
        return MemoryReplay(recording, rate=rate, loop=True, bits=bits)
    raise ValueError(f"source must be one of {SOURCES}, not {source!r}")


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
    return push_rate(lambda i: engine.push(stack[i % len(stack)]), seconds)


def push_rate(push: Callable[[int], object], seconds: float) -> float:
    """Frames/s of ``push(i)`` for i = 0, 1, ... called for ``seconds``."""
    count, started = 0, time.perf_counter()
    while time.perf_counter() - started < seconds:
        push(count)
        count += 1
    return count / (time.perf_counter() - started)


def delivered_engine(recording: Path, seconds: float, bits: int) -> float:
    """Frames/s of ``SlidingWindow.push`` on frames the replay camera reads from the recording on a
    second thread (the daemon's file delivery: one copy per frame beside the pushes), through a
    short queue: the most any daemon fed by this camera can process."""
    engine, _ = filled_engine(recording, bits)
    handed: queue.Queue[np.ndarray] = queue.Queue(maxsize=4)
    stop = threading.Event()

    def deliver() -> None:
        with ReplayCamera(recording, rate=0.0, loop=True, bits=bits) as camera:
            for frame in camera.frames(timeout_s=5.0):
                while not stop.is_set():
                    with contextlib.suppress(queue.Full):
                        handed.put(frame.pixels, timeout=0.1)
                        break
                if stop.is_set():
                    return

    thread = threading.Thread(target=deliver, name="bench-delivery", daemon=True)
    thread.start()
    try:
        for _ in range(8):  # the reader open and its first frames are not measured
            engine.push(handed.get(timeout=30.0))
        return push_rate(lambda _: engine.push(handed.get(timeout=30.0)), seconds)
    finally:
        stop.set()
        thread.join(5.0)


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
                  shape: tuple[int, int], covered: float | None = None, cadence: Cadence = BENCH) -> DaemonConfig:
    """The default daemon configuration on the replay: two large regions (the whole sensor and
    its centre quarter), or with ``covered`` one centred region of that fraction and
    ``estimator.area = "regions"``; evaluated on ``cadence`` (its ``[cadence]``)."""
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
        "cadence": {"stats_interval_s": cadence.stats_every_s, "maps_interval_s": cadence.maps_every_s},
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
              recorder: Recorder | None = None, camera: Camera | None = None,
              cadence: Cadence | None = None) -> Trial:
    """Run the pipeline on ``config`` for ``seconds`` after its window filled and measure over
    those seconds (module docstring). ``wrap``: probes around the instruments' (the interleaved
    capacity holds the pipeline thread in one); ``recorder``: the pipeline's ``[recording]``;
    ``camera``: instead of the config's (:func:`open_source`); ``cadence``: instead of the
    config's ``[cadence]`` (:data:`QUIET`: no evaluation within the trial)."""
    from edgedsm.publish.json_sink import MqttSink

    assert config.mqtt is not None
    gc.collect()  # the previous trial's pipeline and camera (with its mapping of the recording) gone
    mqtt = MqttSink(config.mqtt, config.device.state_dir).start()
    instruments = Instruments()
    try:
        mqtt.wait_connected(10)
        camera = camera or open_camera_for(config)
        probes = instruments.probes()
        pipeline = Pipeline(config, camera, mqtt, cadence=cadence,
                            probes=wrap(probes) if wrap else probes, recorder=recorder)
        # CPU time when the window filled; time and CPU time when the trial's seconds were up
        # (stopping is not measured)
        marks: dict[str, float] = {}
        started = time.monotonic()

        def should_stop() -> bool:
            now, ready_t = time.monotonic(), instruments.ready_t
            if ready_t is not None and "cpu_ready" not in marks:  # once: the process's CPU clock costs
                marks["cpu_ready"] = time.process_time()  # microseconds, and this runs once per loop
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
    trial = Trial(label, rate, pipeline.capture.capacity, pipeline.cadence.stats_every_s, wall, delivered,
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
