"""The evaluator, on its own thread: it takes the snapshots the pipeline thread hands over,
takes the percentiles, turns a copy of the sums into float maps (``maps_from``: the engine's
maps kernel, GIL released, into arrays reused once the sinks let go of them), steps the drying
states and hands typed messages to the sink, beside the next pushes, so that an evaluation never
stalls capture or the engine.

It owns the measurement core's :class:`~edgedsm.measurement.Judgement` (the signal judge and the
drying-state machines: the same object ``analyze`` and ``tune`` judge with), and runs its steps in
the core's order (assess the patches, judge, step the states). A restart (a command, a reload
that keeps nothing) comes from the pipeline thread and a step from the evaluator thread: a lock
guards the state machines, and a generation counter drops an evaluation of the window from before
a restart.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import Counter
from concurrent.futures import Future
from concurrent.futures import TimeoutError as FuturesTimeout

from edgedsm.config import DaemonConfig
from edgedsm.daemon.handover import Snapshot, Status
from edgedsm.daemon.probes import PipelineProbes
from edgedsm.daemon.tau import TauRegions
from edgedsm.daemon.worker import SerialWorker
from edgedsm.drying import Transition
from edgedsm.estimators.snapshot import MapBuffers, maps_from
from edgedsm.measurement import Judgement, view_of
from edgedsm.measurement.kinetics import judged_seconds
from edgedsm.measurement.stages import KineticsStages, StageReached
from edgedsm.measurement.tau import map_block, map_seconds
from edgedsm.messages import (
    Alert,
    AlertKind,
    Clock,
    MapFrame,
    MapStats,
    RegionKinetics,
    RegionState,
    RegionTau,
    StateReport,
    Stats,
    judged_activity,
)
from edgedsm.priority import lower_priority
from edgedsm.publish.sink import Sink

log = logging.getLogger(__name__)

#: How long stopping waits for an evaluation in flight (s); well inside SIGTERM's 2 s.
EVALUATION_TIMEOUT_S = 1.0

#: Niceness of the evaluator thread (edgedsm.priority), relative to the process: 5 weighs it at a
#: third of a normal thread when all contend, which still leaves an evaluation enough CPU at the
#: largest frames benchmarked, where 10 and more judged the states late (docs/bench-e2e.md).
EVALUATOR_NICE = 5


def yield_cores() -> None:
    """The evaluator thread's priority (its executor's initializer)."""
    lower_priority(EVALUATOR_NICE)


class Evaluator:
    """The drying monitor and the thread that evaluates snapshots (see the module docstring)."""

    def __init__(self, config: DaemonConfig, tau: TauRegions, sink: Sink, clock: Clock, counters: Counter[str],
                 probes: PipelineProbes | None = None) -> None:
        self.config = config
        self.tau = tau
        self.sink = sink
        self.clock = clock
        self.counters = counters
        self.probes = probes or PipelineProbes()
        self.map_buffers = MapBuffers()  # float maps, reused once the sinks let go of them
        # the judge (evaluator thread only) and the state machines (under the lock)
        self.judgement = Judgement(config.estimator, config.regions, config.camera.noise, t0=clock.monotonic(),
                                   view=view_of(config.estimator.noise_patch))
        self.signal = self.judgement.judge
        self.stages = KineticsStages(config.kinetics, [r.name for r in config.regions])  # evaluator thread
        self._lock = threading.Lock()  # guards the state machines and the generation
        self._generation = 0  # counts measurement restarts
        self._last_report: StateReport | None = None  # the last one published
        self._executor = SerialWorker("edgedsm-evaluate", initializer=yield_cores)
        self._pending: Future[None] | None = None  # the latest evaluation
        self._last: Future[None] | None = None  # the latest work handed over (an evaluation or an alert)

    # -- called from the pipeline thread ------------------------------------------------------------
    @property
    def busy(self) -> bool:
        """An evaluation handed over is still running."""
        return self._pending is not None and not self._pending.done()

    @property
    def generation(self) -> int:
        """The measurement the next snapshot belongs to."""
        with self._lock:
            return self._generation

    def idle(self, wait: bool = False) -> bool:
        """Whether a new snapshot may be taken and handed over: the previous evaluation has ended
        (its error is re-raised here); ``wait`` lets it end first."""
        if self._pending is None:
            return True
        if not self._pending.done() and not wait:
            return False
        pending, self._pending = self._pending, None
        pending.result()
        return True

    def submit(self, snapshot: Snapshot, wait: bool = False) -> None:
        """Evaluate ``snapshot`` on the evaluator thread (``wait``: to its end, its error raised here)."""
        self._pending = self._last = self._executor.submit(self._analyse, snapshot)
        if wait:
            pending, self._pending = self._pending, None
            pending.result()

    def restart_states(self, why: str) -> None:
        """Every region back to warming up, announced as one ``reset`` alert (as a reload's), not
        as a transition per region; an evaluation still in flight measured the old window."""
        now = self.clock.monotonic()
        with self._lock:
            self.judgement.reset(now, why)
            self._generation += 1
        self._last = self._executor.submit(self.signal.restart)  # on the thread that uses it, in order
        self._last = self._executor.submit(self.stages.reset)
        self.publish_alert(Alert(kind=AlertKind.RESET, t=self.clock.to_wall(now),
                                 reason=f"measurement restarted: {why}; every region warms up again"))
        log.warning("measurement restarted (%s); every region warms up again", why)

    def apply(self, config: DaemonConfig) -> None:
        """New thresholds for the running state machines (states, dwell and trend history kept);
        the regions' names are those running (a reload that renames one restarts instead)."""
        with self._lock:
            self.judgement.apply(config.regions)
            self.config = config
        self._last = self._executor.submit(self.signal.apply, config.estimator, config.regions, config.camera.noise)

    def publish_alert(self, alert: Alert) -> None:
        """Hand an alert to the sink on the evaluator thread (sinks are called from one thread,
        in order: after the evaluation already handed over, before the next)."""
        self._last = self._executor.submit(self._publish_alert, alert)

    def states_line(self) -> str:
        with self._lock:
            return ", ".join(f"{name} {machine.state}" for name, machine in self.judgement.monitor.regions.items())

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
        self._executor.shutdown()
        self.map_buffers = MapBuffers()  # the pooled maps (hundreds of MB at the largest frames)

    # -- the evaluator thread -----------------------------------------------------------------------
    def _publish_alert(self, alert: Alert) -> None:
        try:
            self.sink.publish_alert(alert)
        except Exception as exc:  # logged here: nobody waits for this one's result
            log.error("alert %r could not be handed over: %s", alert.describe(), exc)

    def _analyse(self, snapshot: Snapshot) -> None:
        """Percentiles of the region statistics, drying states, maps from the copied sums,
        messages to the sink."""
        started = time.perf_counter()
        status = snapshot.status
        config = self.config
        estimator = config.estimator.activity
        regions: dict[str, dict[str, MapStats]] = {}
        activities: dict[str, float | None] = {}
        estimates: dict[str, dict[str, float]] = {}
        for name, per_map_moments in snapshot.regions.items():
            if not snapshot.publish_stats:  # states only: the activity means
                estimates[name] = {key: moments.mean for key, moments in per_map_moments.items()}
                if estimator in per_map_moments:
                    activities[name] = per_map_moments[estimator].mean
                continue
            per_map = {key: MapStats(**moments.stats().as_dict()) for key, moments in per_map_moments.items()}
            regions[name] = per_map
            estimates[name] = {key: stats.mean for key, stats in per_map.items() if stats.mean is not None}
            if estimator in per_map:
                activities[name] = per_map[estimator].mean
        taus, interval_s = self._region_taus(snapshot)
        activities.update({name: tau.tau_c_s for name, tau in taus.items() if name in self.tau.judged})
        if estimator == "kinetics":  # τ in s or its bound, judged as τc is; None (held) without light to time
            activities.update({name: judged_seconds(snapshot.kinetics.get(name)) for name in snapshot.kinetics})
        # the core's steps in its order (Judgement.evaluate), the state machines' under the lock
        self._judge_signal(snapshot, estimates)
        plain = dict(activities)  # the statistic before the judge takes the noise floor off
        activities = self.judgement.judged(activities, estimates)
        with self._lock:
            if snapshot.generation != self._generation:
                log.debug("an evaluation of the window before the restart is dropped")
                return
            transitions = self.judgement.step(status.now, activities, ready=snapshot.ready and status.fault is None,
                                              fault=status.fault)
            kinetics, stages = self.stages.step(status.now, snapshot.kinetics, self.clock.to_wall)
            report = self._report(status, estimator, plain, kinetics)
        for transition in transitions:
            self.sink.publish_alert(self._alert(transition))
        for stage in stages:
            self.sink.publish_alert(self._stage_alert(stage))
        if self.probes.states_evaluated is not None:
            self.probes.states_evaluated(status.frames, time.monotonic())
        if not snapshot.publish_stats:
            if transitions:  # a transition is published at once; moves of activity wait for the stats cadence
                self.sink.publish_state(report)
                self._last_report = report
            return
        t = self.clock.to_wall(status.now)
        view = self.judgement.view  # the pixels the signal was judged on, named in each region's signal
        stats = Stats(t=t, frames=status.frames, ready=snapshot.ready, fps=status.fps, laser=status.laser,
                      estimator=estimator, drops=status.drops, camera=status.camera,
                      ambient_level=status.ambient_level, regions=regions,
                      states={name: region.state for name, region in report.regions.items()},
                      warning=status.warning, tau_c=taus, frame_interval_s=interval_s, kinetics=kinetics,
                      recording=status.recording,
                      signal={name: signal.model_copy(update={"view": view})
                              for name, signal in self.signal.signals.items()} if self.signal.on else {},
                      activity=judged_activity(report, self.signal.signals if self.signal.on else {}))
        self.sink.publish_stats(stats)
        # on a transition, and at most once per stats interval when time to dry or activity moved
        if transitions or self._last_report is None or report.moved_from(self._last_report):
            self.sink.publish_state(report)
            self._last_report = report
        if snapshot.publish_maps:
            self._publish_maps(snapshot, t, interval_s)
        if self.probes.evaluated is not None:
            self.probes.evaluated(stats, time.perf_counter() - started)

    def _publish_maps(self, snapshot: Snapshot, t: float, interval_s: float | None) -> None:
        est = self.config.estimator
        frames = snapshot.status.frames
        maps = maps_from(snapshot.engine, self.map_buffers) if snapshot.engine is not None else {}
        origin = {} if snapshot.origin is None else {"origin": list(snapshot.origin)}
        for name, values in maps.items():
            self.counters["maps_published"] += 1
            self.sink.publish_map(MapFrame(name, values, seq=frames, t=t, window=est.window, lag=est.lag,
                                           extra={"estimator": name, "frames": frames, **origin}))
        if snapshot.tau is not None and interval_s is not None and est.tau_c_map:
            self.counters["maps_published"] += 1
            block = map_block(snapshot.tau.shape, est.tau_c_map_block)
            seconds = map_seconds(snapshot.tau, interval_s, block)
            self.sink.publish_map(MapFrame("tau_c", seconds, seq=frames, t=t, window=est.window, lag=est.lag,
                                           extra={"estimator": "tau_c", "unit": "s", "frames": frames,
                                                  "max_lag": est.lags, "frame_interval_s": interval_s,
                                                  "block": block, **origin}))

    def _judge_signal(self, snapshot: Snapshot, estimates: dict[str, dict[str, float]]) -> None:
        """The regions' signal quality and noise floors from the patches (stats cadence), and the
        warnings that began or cleared."""
        if not snapshot.patches or not self.judgement.on:
            return
        t = self.clock.to_wall(snapshot.status.now)
        for warning in self.judgement.assess(snapshot.patches, estimates):
            log.warning("region %s: %s", warning.region, warning.reason, extra={"region": warning.region})
            self.sink.publish_alert(Alert(kind=AlertKind.WARNING, t=t, region=warning.region,
                                          reason=warning.reason + ("; the state is held" if warning.holds else "")))

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

    def _report(self, status: Status, estimator: str, plain: dict[str, float | None],
                kinetics: dict[str, RegionKinetics]) -> StateReport:
        """Every region's state (the lock held); ``plain``: the statistics the judged values came from."""
        judged_on_tau = self.tau.judged
        regions = {name: RegionState(region=name, state=machine.state.value, since=self.clock.to_wall(machine.since),
                                     activity=machine.activity, plain=plain.get(name),
                                     time_to_dry_s=machine.time_to_dry(),
                                     signal=signal.signal if (signal := self.signal.signals.get(name)) else None,
                                     kinetics=kinetics.get(name),
                                     **({"estimator": "tau_c", "tau_c_status": self.tau.status.get(name)}
                                        if name in judged_on_tau else {}))
                   for name, machine in self.judgement.monitor.regions.items()}
        return StateReport(t=self.clock.to_wall(status.now), estimator=estimator, laser=status.laser, regions=regions)

    def _stage_alert(self, stage: StageReached) -> Alert:
        log.info("region %s: %s", stage.region, stage.reason(), extra={"region": stage.region})
        return Alert(kind=AlertKind.STAGE, t=self.clock.to_wall(stage.t), reason=stage.reason(), region=stage.region)

    def _alert(self, transition: Transition) -> Alert:
        # a normal transition is news (INFO); into fault it is an alert (WARNING)
        level = logging.WARNING if transition.to_state.value == "fault" else logging.INFO
        log.log(level, "region %s: %s -> %s (%s)", transition.region, transition.from_state, transition.to_state,
                transition.reason, extra={"region": transition.region, "state": transition.to_state.value})
        return alert_of(transition, self.clock)


def alert_of(transition: Transition, clock: Clock) -> Alert:
    """The alert of a drying-state transition, its time on the wall clock."""
    return Alert(kind=AlertKind.TRANSITION, t=clock.to_wall(transition.t), reason=transition.reason,
                 region=transition.region, from_state=transition.from_state.value,
                 to_state=transition.to_state.value, activity=transition.activity)

