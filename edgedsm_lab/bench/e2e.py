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
   the faster of the bare runs around it (the mean would flatter the daemon). Then the bare
   engine **fed by the file replay**: the replay camera reading the recording on a second thread
   (one copy per frame, the delivery every camera costs) into a short queue, alternating with
   the bare engine alone in ``DELIVERY_PAIRS`` pairs: the most any daemon fed by that camera can
   process. ``--source memory`` takes that copy out of the daemon's trials (the frames served
   from memory, as the bare engine reaches them), so its ratios are the daemon's own cost.
2. **Capacity**: the replay at rate 0 is a source that can wait; the pipeline holds it back when
   its queue is full, so frames/s is what the daemon processes at most.
3. **Capacity interleaved with the bare engine**, drift-free: one capacity trial in which the
   pipeline thread is held between two frames (through its ``frame_taken`` probe) while the bare
   engine, a second engine filled beforehand, pushes the same frames; phases of
   ``PHASE_S`` alternate daemon / bare / bare / daemon ..., and each pair's ratio is taken
   (their median is reported): the machine's drift over minutes cancels, which ratios to runs
   before and after a 20 s trial only bound. Then the same with no evaluation in the trial (no
   drying states, statistics or maps): the daemon's cost per frame alone; the gap between the two
   is what the evaluation cadence costs.
4. **Highest paced rate with zero drops** on the default queue: the replay paced into the
   daemon's drop-oldest queue; bisection from 90 % of the bare engine's rate. Capacity and paced
   rates are given as ratios to the bare engine around each trial. The daemon postpones its
   statistics while the queue is half full (frames first): each trial gives the stats messages
   per second it published and how often they waited. Then the first paced rate once more on the
   daemon's own cadence (a configuration without ``[cadence]``: statistics every 5 s, maps every
   60 s): what a site that keeps the defaults gets at the target.
5. **Latency**: from a frame entering the queue to the drying states that include it being
   judged and their alerts handed to the sink (frame → alert), and to the stats message that
   counts it (frame → stats), p50 and p99, frames after the window filled.
6. **Cost that follows the regions** (``estimator.area = "regions"``): capacity with one
   region covering a decreasing fraction of the sensor, as ms per frame.

Examples:
  edgedsm bench e2e --quick                              # 2048² Mono8, about 5 minutes
  edgedsm bench e2e --size 2048x2048,4096x2168 -o docs/bench-e2e.md
  edgedsm bench e2e --size 1024x1024 --pixel-format Mono12p
"""

from __future__ import annotations

import itertools
import math
import statistics
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from edgedsm.config import DaemonConfig
from edgedsm.daemon.pipeline import Cadence
from edgedsm.daemon.probes import PipelineProbes
from edgedsm.frames import Frame
from edgedsm_lab.bench.e2e_trial import (
    BENCH,
    QUIET,
    RECORDED_FRAMES,
    SHIPPED,
    WINDOW,
    Trial,
    bare_engine,
    daemon_config,
    delivered_engine,
    filled_engine,
    forget_recording,
    held_recording,
    make_recording,
    open_source,
    run_trial,
    unpack_ms,
)

HELP = "the daemon end to end (replay → pipeline → MQTT): bare engine vs daemon, zero-drop rate, latency"

BARE_RUN_S = 6.0  # the bare engine's run after each trial (plus filling its window)
#: Interleaved capacity: seconds per phase (below the bench config's camera.grab_timeout_s, so
#: that a held pipeline is not a camera outage), the pause before a bare phase (the evaluation in
#: flight ends) and the daemon's seconds at capacity before the first phase.
PHASE_S, SETTLE_S, SETTLE_FIRST_S = 3.0, 0.3, 3.0
PHASE_PAIRS = 8  # daemon/bare pairs (quick: half)
#: The issue's target: the daemon sustains this fraction of the bare engine with zero drops (the
#: paced trials start there).
TARGET_RATIO = 0.9
DELIVERY_PAIRS = 3  # bare engine alone / fed from the file, BARE_RUN_S each
PIXEL_FORMATS = {"Mono8": 8, "Mono12p": 12, "Mono16": 16}
COVERED = (1.0, 0.25, 0.0625, 0.01)  # fractions of the sensor the one region covers (area trials)


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


def interleaved_capacity(recording: Path, config: DaemonConfig, bits: int, pairs: int,
                         source: str = "file", cadence: Cadence | None = None) -> Interleaved:
    """The daemon at its capacity and the bare engine in alternating phases of one trial (see the
    module docstring); the bare engine's window is filled before the trial. ``cadence``: the
    daemon's evaluations (:data:`~edgedsm_lab.bench.e2e_trial.QUIET`: none)."""
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
        trial = run_trial("interleaved", config, rate=None, seconds=seconds, wrap=alternation.wrap,
                          camera=open_source(config, source, recording, 0.0, bits), cadence=cadence)
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
    source: str = "file"  # where the replay took its frames (e2e_trial.SOURCES)
    delivery: list[float] = field(default_factory=list)  # bare engine fed from the file ÷ bare, per pair
    quiet: Interleaved | None = None  # the interleaved capacity without evaluations (e2e_trial.QUIET)
    shipped: Trial | None = None  # the first paced rate again, on the daemon's own cadence (e2e_trial.SHIPPED)

    @property
    def delivery_ratio(self) -> float:
        """The bare engine fed by the file replay on a second thread ÷ the bare engine alone (median)."""
        return statistics.median(self.delivery) if self.delivery else float("nan")

    @property
    def best(self) -> Trial | None:
        return best_zero_drop(self.paced)

    @property
    def bare_fps(self) -> float:
        """The bare engine's rate over the run (median of its runs)."""
        return statistics.median(self.bare_runs)


def measure_size(shape: tuple[int, int], pixel_format: str, workdir: Path, port: int, *, seconds: float,
                 max_trials: int, areas: bool, say: Callable[[str], None], pairs: int = PHASE_PAIRS,
                 source: str = "file") -> SizeResult:
    bits = PIXEL_FORMATS[pixel_format]
    name = f"{shape[1]}x{shape[0]}"
    say(f"{name} {pixel_format}: recording {RECORDED_FRAMES} frames ...")
    recording = make_recording(workdir / f"{name}-{bits}.npy", shape, bits)
    trial_id = itertools.count()

    bare_runs: list[float] = []

    def bare(run_seconds: float) -> float:
        bare_runs.append(bare_engine(recording, run_seconds, bits))
        return bare_runs[-1]

    def trial(label: str, rate: float | None, covered: float | None = None, cadence: Cadence = BENCH) -> Trial:
        config = daemon_config(recording, port, workdir / f"state-{next(trial_id)}", rate or 0, bits, shape, covered,
                               cadence)
        camera = open_source(config, source, recording, rate or 0.0, bits)
        result = run_trial(label, config, rate=rate, seconds=seconds, covered=covered or 1.0, camera=camera)
        if covered is not None:  # the area trials compare with each other, not with the bare engine
            return result
        before = bare_runs[-1]
        # the machine's speed drifts: the engine around the trial, the faster run (never flattering)
        result.bare_fps = max(before, bare(BARE_RUN_S))
        say(f"  {label}: rate {result.rate or 'max'}, {result.fps:.1f} frames/s processed, {result.drops} dropped; "
            f"bare engine around it {result.bare_fps:.1f} frames/s")
        return result

    if source == "memory":
        held_recording(recording)  # read once, before the first trial
    say(f"  bare engine, {seconds:g} s ...")
    say(f"  bare engine: {bare(seconds):.1f} frames/s")
    delivery = []  # pairs of bare / fed from the file, alternating which goes first
    for pair in range(DELIVERY_PAIRS):
        if pair % 2 == 0:
            alone, fed = bare_engine(recording, BARE_RUN_S, bits), delivered_engine(recording, BARE_RUN_S, bits)
        else:
            fed, alone = delivered_engine(recording, BARE_RUN_S, bits), bare_engine(recording, BARE_RUN_S, bits)
        delivery.append(fed / alone)
    say(f"  bare engine fed by the file replay on a second thread ÷ alone: "
        f"{', '.join(f'{r:.0%}' for r in delivery)}")
    capacity = trial("capacity", None)
    say(f"  capacity interleaved with the bare engine, {pairs} pairs of {PHASE_S:g} s phases ...")
    interleaved = interleaved_capacity(recording, daemon_config(recording, port, workdir / f"state-{next(trial_id)}",
                                                                0, bits, shape), bits, pairs, source)
    say(f"  interleaved: daemon ÷ bare {', '.join(f'{r:.0%}' for r in interleaved.ratios)}; "
        f"median {interleaved.ratio:.0%}")
    say("  the same without evaluations (what the evaluations cost) ...")
    quiet = interleaved_capacity(recording, daemon_config(recording, port, workdir / f"state-{next(trial_id)}", 0,
                                                          bits, shape), bits, pairs, source, QUIET)
    say(f"  without evaluations: daemon ÷ bare {', '.join(f'{r:.0%}' for r in quiet.ratios)}; "
        f"median {quiet.ratio:.0%}")
    # the first paced trial is at the target, 90 % of the bare engine's latest run rounded up (so
    # that passing it shows the target met), on a grid of at most 2 % of the rate (87 % and 90 %
    # told apart at any size), bisected down to adjacent grid points
    rate_now = bare_runs[-1]
    step = 5.0 if rate_now >= 250 else 1.0 if rate_now >= 50 else 0.5
    target = step * max(1, math.ceil(TARGET_RATIO * rate_now / step))
    paced = search_rate(lambda rate: trial("paced", rate), start=target, ceiling=max(rate_now, capacity.fps) * 1.05,
                        max_trials=max_trials, resolution=step, step=step)
    # the target once more with the daemon's own cadence: what a site that keeps the defaults gets
    shipped = trial("paced, the daemon's own cadence", target, cadence=SHIPPED)
    covered = [trial(f"area, {100 * c:g} %", None, c) for c in COVERED] if areas else []
    forget_recording(recording)
    recording.unlink()
    return SizeResult(shape, pixel_format, bare_runs, unpack_ms(shape, pixel_format), capacity,
                      sorted(paced, key=lambda t: t.rate or 0.0), covered, interleaved, source, delivery, quiet,
                      shipped)

