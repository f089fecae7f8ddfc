"""Evaluation: the streaming engine and, beside it, region statistics, drying states and messages.

The pipeline thread pushes frames into the engine and, on the states and stats cadence, reduces
the engine's live sums to region statistics between two pushes
(:func:`edgedsm.estimators.region_stats.region_moments`: one pass over the rows the regions cover,
each pixel's maps computed once whatever the regions holding it, no float maps and no copy of
the sums; with two large regions about one push at 2048², half a push at 4096×2168).
States are evaluated on their own, faster cadence from the activity map's region means only; the
full statistics (count, mean, deviation, percentile sample of every map) on the stats cadence.
Only on the maps cadence does it copy the sums (``engine.snapshot()``). It hands a
:class:`Snapshot` of all that to one evaluator thread, which takes the percentiles, turns a copy
of the sums into float maps (``maps_from``: the engine's maps kernel, GIL released, into arrays
reused once the sinks let go of them), steps the
drying states and hands typed messages to the sink, beside the next pushes, so an evaluation
never stalls capture or the engine.

With ``estimator.area = "regions"`` the engine sees only the bounding box of all regions (frames
are cropped before the push): the cost follows the regions, and the published maps cover that
box (their ``origin`` gives its top-left corner in camera pixels).

The drying monitor is shared by both threads (a reset comes from a command on the pipeline
thread, a step from the evaluator): a lock guards it.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import TimeoutError as FuturesTimeout
from dataclasses import dataclass, field

import numpy as np

from edgedsm.analysis import RegionBox, bounding_box
from edgedsm.config import DaemonConfig
from edgedsm.daemon.probes import PipelineProbes
from edgedsm.daemon.tau import TauRegions, engine_estimators, map_block
from edgedsm.drying import DryingMonitor, Transition
from edgedsm.errors import ConfigError, FrameError
from edgedsm.estimators import ESTIMATORS, SlidingWindow
from edgedsm.estimators.region_stats import Moments, RegionLayout, RegionPlan, region_moments
from edgedsm.estimators.snapshot import EngineSnapshot, MapBuffers, TauSnapshot, maps_from
from edgedsm.estimators.streaming import PARALLEL_MIN_PIXELS, TAU_BATCH
from edgedsm.estimators.tau_pooled import pooled_covariances
from edgedsm.frames import Frame
from edgedsm.messages import (
    Alert,
    AlertKind,
    Clock,
    LaserState,
    MapFrame,
    MapStats,
    RegionState,
    RegionTau,
    StateReport,
    Stats,
)
from edgedsm.priority import lower_priority
from edgedsm.publish.sink import Sink

log = logging.getLogger(__name__)

#: How long stopping waits for an evaluation in flight (s); well inside SIGTERM's 2 s.
EVALUATION_TIMEOUT_S = 1.0
#: Frames smaller than this are processed by one kernel thread (unless estimator.threads says).
SMALL_FRAME_PIXELS = 1 << 18


#: Niceness of the evaluator thread (edgedsm.priority), relative to the process: 5 weighs it at a
#: third of a normal thread when all contend, which still covers an evaluation's CPU at 4096×2168
#: (states twice a second, the longest evaluation 0.4 s); at 10 an evaluation took up to 1.1 s
#: and at 15 up to 2.9 s, the states judged late (2-core EPYC, bench e2e at the engine's capacity).
EVALUATOR_NICE = 5


def yield_cores() -> None:
    """The evaluator thread's priority (its executor's initializer)."""
    lower_priority(EVALUATOR_NICE)


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


#: Pixels of the probe engine whose arrays give the per-pixel memory of the real one.
PROBE_PIXELS = 8
#: Bytes per pixel of the float maps: two sets of S1, S2, S3 and σ (float64; a second set while
#: a sink still holds the first).
MAP_BYTES_PER_PIXEL = 2 * 4 * 8


def engine_bytes_per_pixel(probe: SlidingWindow) -> float:
    """Bytes per pixel the daemon keeps for an engine like ``probe`` (any size, its bit depth
    known): the engine's own arrays (ring and sums, τc's included), the copy of the sums for the
    maps, the float maps, and τc's copy of its sums (estimated as large as the engine's)."""
    own = probe.array_bytes()
    tau = sum(size for name, size in own.items() if name in ("products", "edges", "retired", "total", "total_sq"))
    copies = probe.snapshot_buffers().nbytes + (tau if "tau_c" in probe.estimators else 0)
    pixels = probe.shape[0] * probe.shape[1]
    return (sum(own.values()) + copies) / pixels + MAP_BYTES_PER_PIXEL


def check_engine_memory(frame: Frame, bytes_per_pixel: float, pixels: int | None = None) -> None:
    """Refuse, with the config keys to change, an engine that cannot fit in memory (``pixels``:
    what the engine sees, when not the whole frame; ``bytes_per_pixel``: engine_bytes_per_pixel)."""
    needed = (pixels or frame.pixels.size) * bytes_per_pixel
    free = available_memory()
    if free is not None and needed > 0.8 * free:
        raise ConfigError(f"estimator.window: the estimator for {frame.shape[1]}x{frame.shape[0]} frames needs "
                          f"{needed / 2**30:.1f} GiB (its window, sums and their copies); this machine has "
                          f"{free / 2**30:.1f} GiB available (use a shorter window or max_lag, mode = 'tumbling' "
                          "or 'exponential', or area = 'regions')")


@dataclass(frozen=True)
class Status:
    """What the pipeline knows beside the maps at one evaluation (monotonic ``now``)."""

    now: float
    frames: int
    fps: float
    laser: LaserState
    drops: dict[str, int]
    camera: dict[str, float | int | str | None]
    ambient_level: float | None
    warning: str | None
    fault: str | None


@dataclass(frozen=True)
class Snapshot:
    """One evaluation's input, handed from the pipeline thread to the evaluator thread."""

    status: Status
    ready: bool
    engine: EngineSnapshot | None = None  # a copy of the sums when maps are published (else None);
    # valid until the next copy, which reuses its buffers
    publish_maps: bool = False
    publish_stats: bool = True  # False: the drying states only (activity means, no stats message)
    tau: TauSnapshot | None = None  # τc's sums, when τc is estimated and this evaluation needs it
    #: region -> map -> moments, from the live sums on the pipeline thread (empty before the window
    #: is full); states only: the judged map's means
    regions: dict[str, dict[str, Moments]] = field(default_factory=dict)
    #: the measurement it belongs to: an evaluation taken before a rebaseline is not judged after it
    generation: int = 0


class Evaluation:
    """The engine, the region masks and the drying monitor (see the module docstring)."""

    def __init__(self, config: DaemonConfig, sink: Sink, clock: Clock, counters: Counter[str],
                 probes: PipelineProbes | None = None) -> None:
        self.config = config
        self.sink = sink
        self.clock = clock
        self.counters = counters
        self.probes = probes or PipelineProbes()
        self.engine: SlidingWindow | None = None
        self.frame_shape: tuple[int, int] | None = None  # fixed by the first frame
        self.regions: dict[str, RegionBox] = {}  # in the engine's coordinates
        self._layout = RegionLayout.of({})  # the same, prepared for region_moments
        self.crop: tuple[slice, slice] | None = None  # estimator.area = "regions": the box the engine sees
        self.monitor = DryingMonitor({r.name: r.thresholds() for r in config.regions}, t0=clock.monotonic())
        self.monitor_lock = threading.Lock()
        self._generation = 0  # counts measurement restarts (rebaseline); guarded by monitor_lock
        self._last_report: StateReport | None = None  # the last one published
        self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="edgedsm-evaluate",
                                            initializer=yield_cores)
        self._pending: Future[None] | None = None  # the latest analysis
        self._buffers: EngineSnapshot | None = None  # the latest snapshot, overwritten by the next
        self._map_buffers = MapBuffers()  # float maps, reused once the sinks let go of them
        self.tau = TauRegions(config)  # τc: frame interval, region pixels, snapshot (edgedsm.daemon.tau)
        self._tau_buffers: TauSnapshot | None = None
        self.warm_up()
        self._last: Future[None] | None = None  # the latest work handed to the evaluator thread

    def warm_up(self) -> None:
        """Load every compiled kernel an evaluation uses, on a small engine, before frames flow:
        loading them later (hundreds of ms, holding the GIL) would stall the pipeline thread and
        overflow the queue at the first push and the first evaluation."""
        est = self.config.estimator
        deep = self.config.camera.pixel_format not in (None, "Mono8")
        side = 256  # at least PARALLEL_MIN_PIXELS: the parallel kernels real frames use
        window = est.lag + 2
        if self.tau.on:  # long enough for every τc kernel (sliding batches need N >= K + TAU_BATCH)
            window = max(window, est.lags + TAU_BATCH + 2)
        engine = SlidingWindow((side, side), window=window, lag=est.lag, q=est.q, bits=16 if deep else 8,
                               estimators=engine_estimators(self.config), mode=est.mode, threads=est.threads,
                               max_lag=est.lags if self.tau.on else None)
        frame = np.zeros((side, side), np.uint16 if deep else np.uint8)
        for _ in range(window + TAU_BATCH + 1):  # past a full batch of lag products
            engine.push(frame)
        mask = np.zeros((side, side), bool)
        mask[1:-1, 1:-1] = True
        layout = RegionLayout.of({name: RegionPlan.of(RegionBox.of(region), (side, side))
                                  for name, region in (("all", np.ones_like(mask)), ("inner", mask))})
        maps_from(engine.snapshot(ESTIMATORS))
        wanted = [ESTIMATORS] + ([[est.activity]] if est.activity in ESTIMATORS else [])
        for parallel in (False, True):  # which one runs depends on the frame's size, not known yet
            for names in wanted:
                region_moments(engine.snapshot(names, live=True), layout, names, spread=names is ESTIMATORS,
                               parallel=parallel)
        if self.tau.on:  # the pooled-covariance kernels of the regions and the block map
            tau = engine.tau_snapshot()
            self.tau.map_seconds(tau, 1.0, block=2)
            pooled_covariances(tau.window, tau.total, tau.total_sq, tau.products, tau.edges, tau.ends,
                               np.flatnonzero(mask), tau.lags)

    # -- pipeline thread --------------------------------------------------------------------------
    def prepare(self, frame: Frame) -> None:
        """At the first frame (before the laser goes on): the engine and the region masks for its
        shape. A region outside the frame or a window too big for memory is a ``ConfigError``."""
        if self.frame_shape is None:
            self._make_engine(frame)

    def push(self, frame: Frame, dark: np.ndarray | None) -> bool:
        """Push one frame (ambient-corrected with ``dark`` when configured); False if refused."""
        if self.engine is None:  # the first frame fixes the shape; later misfits are refused
            self._make_engine(frame)
        assert self.engine is not None
        pixels = frame.pixels
        if self.crop is not None and pixels.shape == frame.shape:
            pixels = np.ascontiguousarray(pixels[self.crop])
            dark = dark[self.crop] if dark is not None and dark.shape == frame.shape else None
        if self.config.estimator.ambient_correction and dark is not None and dark.shape == pixels.shape:
            # ambient-corrected S2: the dark level is subtracted before normalising (saturating at 0)
            pixels = np.subtract(pixels, np.minimum(pixels, dark))
        try:
            self.engine.push(pixels)
            self.tau.interval.saw(frame)
        except FrameError as exc:
            self.counters["dropped_invalid"] += 1
            log.warning("frame %d dropped: %s", frame.seq, exc)
            if self.probes.frame_dropped is not None:
                self.probes.frame_dropped(frame, "invalid")
            return False
        return True

    @property
    def busy(self) -> bool:
        """An evaluation handed over is still running."""
        return self._pending is not None and not self._pending.done()

    @property
    def ready(self) -> bool:
        return self.engine is not None and self.engine.ready

    def _make_engine(self, frame: Frame) -> None:
        est = self.config.estimator
        threads = est.threads
        if threads is None and frame.pixels.size < SMALL_FRAME_PIXELS:
            # a parallel pass over a small frame costs more in thread wake-ups than it saves, and
            # stalls badly when the capture thread competes for the cores
            threads = 1
        masks = {r.name: r.mask(frame.shape, self.config.base_dir) for r in self.config.regions}
        regions = {name: RegionBox.of(mask) for name, mask in masks.items()}
        shape = frame.shape
        if est.area == "regions" and masks:
            rows, cols = self.crop = bounding_box(list(masks.values()))
            regions = {name: box.shifted(rows, cols) for name, box in regions.items()}
            shape = (rows.stop - rows.start, cols.stop - cols.start)
        def engine(shape: tuple[int, int]) -> SlidingWindow:
            return SlidingWindow(shape, window=est.window, lag=est.lag, q=est.q, bits=frame.bits,
                                 estimators=engine_estimators(self.config), mode=est.mode, threads=threads,
                                 max_lag=est.lags if self.tau.on else None)

        # the same arrays for a few pixels first: a window too big for memory is refused before
        # anything large is allocated
        check_engine_memory(frame, engine_bytes_per_pixel(engine((1, PROBE_PIXELS))), pixels=shape[0] * shape[1])
        self.engine = engine(shape)
        # the arrays of the maps evaluation (a copy of the sums, the float maps) written once now,
        # before frames flow: at the first maps their fresh pages would stall both threads
        # (0.35 s on the pipeline thread, 0.3 s on the evaluator at 4096×2168, 2-core EPYC)
        self._buffers = self.engine.snapshot_buffers(ESTIMATORS)
        self._map_buffers.reserve(self._buffers)
        self.regions = regions
        self._layout = RegionLayout.of({name: RegionPlan.of(box, shape) for name, box in regions.items()})
        self.tau.prepare(regions, shape)
        self.frame_shape = frame.shape

    def reset(self, why: str, states: bool = True) -> None:
        """Empty the estimator window; with ``states``, every region goes back to warming up,
        announced as one ``reset`` alert (as a reload's), not as a transition per region."""
        if self.engine is not None:
            self.engine.reset()
        if states:
            now = self.clock.monotonic()
            with self.monitor_lock:
                self.monitor.reset(now, why)
                self._generation += 1  # an evaluation still in flight measured the old window
            self.publish_alert(Alert(kind=AlertKind.RESET, t=self.clock.to_wall(now),
                                     reason=f"measurement restarted: {why}; every region warms up again"))
            log.warning("measurement restarted (%s); every region warms up again", why)
            return
        log.info("measurement restarted (%s)", why)

    def publish_alert(self, alert: Alert) -> None:
        """Hand an alert to the sink on the evaluator thread (sinks are called from one thread,
        in order: after the evaluation already handed over, before the next)."""
        self._last = self._executor.submit(self._publish_alert, alert)

    def _publish_alert(self, alert: Alert) -> None:
        try:
            self.sink.publish_alert(alert)
        except Exception as exc:  # logged here: nobody waits for this one's result
            log.error("alert %r could not be handed over: %s", alert.describe(), exc)

    def evaluate(self, status: Status, maps_due: bool, wait: bool = False, stats_due: bool = True) -> Snapshot | None:
        """Region statistics from the sums now (and a copy of the sums when maps are due), the
        rest on the evaluator thread; None if skipped.

        An evaluation that is due while the previous one still runs is skipped (the caller
        retries);
        ``wait`` makes this one run to its end (and re-raises its error here). Without
        ``stats_due`` only the drying states are evaluated (no stats message, no maps).
        """
        if self._pending is not None:
            if not self._pending.done() and not wait:
                return None  # the pipeline tries again at its next loop
            pending, self._pending = self._pending, None
            pending.result()  # re-raises an error of the evaluator thread here
        started = time.perf_counter()
        ready = self.ready
        engine = tau = None
        moments: dict[str, dict[str, Moments]] = {}
        publish_maps = ready and maps_due and stats_due
        if ready and self.engine is not None:
            wanted = self._snapshot_estimators(stats_due)
            if wanted:
                # the live sums, read between two pushes on the thread that pushes: no copy
                moments = region_moments(self.engine.snapshot(wanted, live=True), self._layout, wanted,
                                         spread=stats_due, parallel=self.engine.shape[0] * self.engine.shape[1]
                                         >= PARALLEL_MIN_PIXELS)
            if publish_maps:
                # the previous snapshot's analysis has ended (checked above): its buffers are reused
                engine = self._buffers = self.engine.snapshot(ESTIMATORS, into=self._buffers)
            tau = self.tau.take(self.engine, stats_due, self._tau_buffers)
            self._tau_buffers = tau or self._tau_buffers
        with self.monitor_lock:
            generation = self._generation
        snapshot = Snapshot(status, ready, engine, publish_maps=publish_maps, publish_stats=stats_due, tau=tau,
                            regions=moments, generation=generation)
        if self.probes.snapshot_taken is not None:
            self.probes.snapshot_taken(snapshot, time.perf_counter() - started)
        self._pending = self._last = self._executor.submit(self._analyse, snapshot)
        if wait:
            pending, self._pending = self._pending, None
            pending.result()
        return snapshot

    def _snapshot_estimators(self, stats_due: bool) -> list[str]:
        """The S maps an evaluation needs: all for the stats; for the states alone, the judged one
        if a region is judged on it (none when every region is judged on τc)."""
        if stats_due:
            return list(ESTIMATORS)
        activity = self.config.estimator.activity
        judged_on_activity = any(not region.on_tau for region in self.config.regions)
        return [activity] if activity in ESTIMATORS and judged_on_activity else []

    def finish(self) -> None:
        """Let the work handed over end (bounded), so alerts and maps are not lost."""
        pending, self._pending, self._last = self._last, None, None
        if pending is not None:
            try:
                pending.result(timeout=EVALUATION_TIMEOUT_S)
            except FuturesTimeout:
                log.warning("the last evaluation did not finish within %.1f s", EVALUATION_TIMEOUT_S)
            except Exception:
                log.exception("the last evaluation failed")
        self._executor.shutdown(wait=False)
        # the window's ring is the bulk of the daemon's memory (N frames): released now, not
        # when the garbage collector gets to the pipeline (a reload builds a new one at once)
        self.engine = self._buffers = self._tau_buffers = None
        self._map_buffers = MapBuffers()  # and the pooled maps (hundreds of MB at 4096×2168)

    def states_line(self) -> str:
        with self.monitor_lock:
            return ", ".join(f"{name} {machine.state}" for name, machine in self.monitor.regions.items())

    # -- evaluator thread ---------------------------------------------------------------------------
    def _analyse(self, snapshot: Snapshot) -> None:
        """Percentiles of the region statistics, drying states, maps from the copied sums,
        messages to the sink."""
        started = time.perf_counter()
        status = snapshot.status
        estimator = self.config.estimator.activity
        regions: dict[str, dict[str, MapStats]] = {}
        activities: dict[str, float] = {}
        for name, per_map_moments in snapshot.regions.items():
            if not snapshot.publish_stats:  # states only: the activity means
                if estimator in per_map_moments:
                    activities[name] = per_map_moments[estimator].mean
                continue
            per_map = {key: MapStats(**moments.stats().as_dict()) for key, moments in per_map_moments.items()}
            regions[name] = per_map
            mean = per_map[estimator].mean if estimator in per_map else None
            if mean is not None:
                activities[name] = mean
        taus, interval_s = self._region_taus(snapshot)
        activities.update({name: tau.tau_c_s for name, tau in taus.items() if name in self.tau.judged})
        with self.monitor_lock:
            if snapshot.generation != self._generation:
                log.debug("an evaluation of the window before the restart is dropped")
                return
            transitions = self.monitor.step(status.now, activities, ready=snapshot.ready and status.fault is None,
                                             fault=status.fault)
            report = self._report(status, estimator)
        for transition in transitions:
            self.sink.publish_alert(self._alert(transition))
        if self.probes.states_evaluated is not None:
            self.probes.states_evaluated(status.frames, time.monotonic())
        if not snapshot.publish_stats:
            if transitions:  # a transition is published at once; moves of activity wait for the stats cadence
                self.sink.publish_state(report)
                self._last_report = report
            return
        t = self.clock.to_wall(status.now)
        stats = Stats(t=t, frames=status.frames, ready=snapshot.ready, fps=status.fps, laser=status.laser,
                      estimator=estimator, drops=status.drops, camera=status.camera,
                      ambient_level=status.ambient_level, regions=regions,
                      states={name: region.state for name, region in report.regions.items()},
                      warning=status.warning, tau_c=taus, frame_interval_s=interval_s)
        self.sink.publish_stats(stats)
        # on a transition, and at most once per stats interval when time to dry or activity moved
        if transitions or self._last_report is None or report.moved_from(self._last_report):
            self.sink.publish_state(report)
            self._last_report = report
        if snapshot.publish_maps:
            maps = maps_from(snapshot.engine, self._map_buffers) if snapshot.engine is not None else {}
            est = self.config.estimator
            origin = {} if self.crop is None else {"origin": [self.crop[1].start, self.crop[0].start]}
            for name, values in maps.items():
                self.counters["maps_published"] += 1
                self.sink.publish_map(MapFrame(name, values, seq=status.frames, t=t, window=est.window, lag=est.lag,
                                               extra={"estimator": name, "frames": status.frames, **origin}))
            if snapshot.tau is not None and interval_s is not None and est.tau_c_map:
                self.counters["maps_published"] += 1
                block = map_block(snapshot.tau.shape, est.tau_c_map_block)
                seconds = self.tau.map_seconds(snapshot.tau, interval_s, block)
                self.sink.publish_map(MapFrame("tau_c", seconds, seq=status.frames, t=t, window=est.window, lag=est.lag,
                                               extra={"estimator": "tau_c", "unit": "s", "frames": status.frames,
                                                      "max_lag": est.lags, "frame_interval_s": interval_s,
                                                      "block": block, **origin}))
        if self.probes.evaluated is not None:
            self.probes.evaluated(stats, time.perf_counter() - started)

    def _region_taus(self, snapshot: Snapshot) -> tuple[dict[str, RegionTau], float | None]:
        """Each region's τc in seconds (all with the stats, the judged ones for the states alone) and
        the frame interval used; nothing when the snapshot has no τc sums or Δt is not known."""
        interval_s = self.tau.interval.seconds(snapshot.status.fps) if snapshot.tau is not None else None
        if snapshot.tau is None or interval_s is None:
            return {}, None
        for region, problem in self.tau.threshold_problems(interval_s).items():
            log.warning("region %s: %s", region, problem, extra={"region": region})
            self.sink.publish_alert(Alert(kind=AlertKind.WARNING, t=self.clock.to_wall(snapshot.status.now),
                                          reason=problem, region=region))
        names = None if snapshot.publish_stats else self.tau.judged
        return self.tau.regions(snapshot.tau, interval_s, names), interval_s

    def _report(self, status: Status, estimator: str) -> StateReport:
        """Every region's state (the monitor lock held)."""
        judged_on_tau = self.tau.judged
        regions = {name: RegionState(region=name, state=machine.state.value, since=self.clock.to_wall(machine.since),
                                     activity=machine.activity, time_to_dry_s=machine.time_to_dry(),
                                     **({"estimator": "tau_c", "tau_c_status": self.tau.status.get(name)}
                                        if name in judged_on_tau else {}))
                   for name, machine in self.monitor.regions.items()}
        return StateReport(t=self.clock.to_wall(status.now), estimator=estimator, laser=status.laser, regions=regions)

    def _alert(self, transition: Transition) -> Alert:
        log.warning("region %s: %s -> %s (%s)", transition.region, transition.from_state, transition.to_state,
                    transition.reason, extra={"region": transition.region, "state": transition.to_state.value})
        return alert_of(transition, self.clock)


def alert_of(transition: Transition, clock: Clock) -> Alert:
    """The alert of a drying-state transition, its time on the wall clock."""
    return Alert(kind=AlertKind.TRANSITION, t=clock.to_wall(transition.t), reason=transition.reason,
                 region=transition.region, from_state=transition.from_state.value,
                 to_state=transition.to_state.value, activity=transition.activity)
