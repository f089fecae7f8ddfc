"""A tuning session: the reference run read once per window setting, every candidate scored,
within a time budget (docs/commissioning.md).

The settings are tried in order of likelihood (N near 100, m near 5 first: the paper's and the
daemon's defaults), one streaming pass each; a setting's time (its pass, its cost timings and its
scoring) is measured and no setting is begun that the budget cannot hold if it takes as long as
the last (the first always runs). The candidates of a setting are every judgeable estimator asked
for (``estimators``, default series.DEFAULT_CANDIDATES: all but GD): more estimators make each setting longer,
so the same budget covers fewer settings. Each candidate's cost per frame is measured by the
engine on frames of the run at the camera's size (the whole frame, or the regions' bounding box
with ``estimator.area = "regions"``), as the daemon would push them; Fujii's at q = 0, the q its
daemon runs at. A candidate whose replay of the run skips a state of wet -> drying -> dry (its
drying band crossed within the dwell) is not recommended, only listed, marked (:func:`choose`).

The kinetics (asked for, as by default) are measured in the first pass, with the config's
``[kinetics]`` when it has one on, else the daemon's defaults; its cost per frame is its push
measured on the same frames (every region) plus its read, timed on the references the run left,
at the daemon's states cadence. A run that does not allow it (two recordings joined: references
across the join compare two surfaces; frame times that do not follow one interval: the ages are
counted in frames) lists it as not scored, with the reason.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np

from edgedsm.config import DaemonConfig
from edgedsm.config.kinetics import KineticsSection
from edgedsm.errors import DataError
from edgedsm.estimators import registry
from edgedsm.estimators.region_box import bounding_box
from edgedsm.tuning.candidates import USABLE_AUC, Candidate, Outcome, candidates, evaluate, pareto, recommend
from edgedsm.tuning.scoring import ORDER
from edgedsm.tuning.series import (
    DEFAULT_CANDIDATES,
    KINETICS,
    Series,
    Setting,
    kinetics_cost,
    push_cost,
    run_pass,
)

WINDOWS = (100, 200, 50, 400)
LAGS = (5, 10, 2, 1, 20)
COST_FRAMES = 16  # frames of the run each cost is timed over (repeated)
MAX_SAMPLES = 400  # samples per pass at most (the step grows on long runs: the states are judged every step)
STATE_STEP_S = 0.5  # the daemon judges the states twice a second
#: a step between frame times outside (1 ± GAP)·Δt is a dropped frame or a burst: no kinetics (its
#: ages are counted in frames); a camera's jitter within it averages out over an age
GAP = 0.5


@dataclass(frozen=True)
class Run:
    """The reference run: a way to read its frames again, its size, clock and marks (seconds from
    its first frame)."""

    frames: Callable[[], Iterator[np.ndarray]]
    count: int
    bits: int | None
    dt: float
    times_s: np.ndarray | None
    wet_until_s: float
    dry_from_s: float
    name: str
    joined: bool = False  # two recordings (--wet, --dry) one after the other, not one drying

    def kinetics_problem(self) -> str | None:
        """Why the kinetics cannot be scored on this run (None: they can)."""
        if self.joined:
            return "two recordings joined: the reference frames across the join compare two surfaces"
        if self.times_s is not None and self.times_s.size > 2:
            steps = np.diff(self.times_s)
            worst = steps[int(np.argmax(np.abs(steps - self.dt)))]
            if abs(worst - self.dt) > GAP * self.dt:
                return (f"the frame times do not follow one interval (a step of {float(worst):.3g} s at "
                        f"Δt {self.dt:.3g} s: dropped frames or bursts): the kinetics count ages in frames")
        return None

    @property
    def duration_s(self) -> float:
        return float(self.times_s[-1]) if self.times_s is not None else (self.count - 1) * self.dt

    def frame_at(self, seconds: float) -> int:
        """The last frame at or before ``seconds``."""
        if self.times_s is not None:
            return int(np.searchsorted(self.times_s, seconds, side="right")) - 1
        return math.floor(seconds / self.dt + 1e-9)


@dataclass
class Result:
    run: Run
    series: list[Series] = field(default_factory=list)
    outcomes: list[Outcome] = field(default_factory=list)
    chosen: Outcome | None = None
    reason: str = ""
    skipped: list[Setting] = field(default_factory=list)  # settings the budget left out
    excluded: list[tuple[Candidate, str]] = field(default_factory=list)  # candidates that could not be scored
    seconds: float = 0.0


def settings_for(run: Run, windows: Sequence[int] = WINDOWS, lags: Sequence[int] = LAGS,
                 modes: Sequence[str] = ("sliding",)) -> list[Setting]:
    """The settings that fit the run, likeliest first: a window must fill within the wet part (so
    that there are wet samples) and leave dry samples; the lag at most a quarter of the window."""
    wet_frames = run.frame_at(run.wet_until_s) + 1
    fitting = [n for n in windows if n <= wet_frames and n < run.count]
    if not fitting:
        raise DataError(f"{run.name}: the run is too short for a window: the wet part holds {wet_frames} frames, "
                        f"the shortest window tried is {min(windows)} (record longer, or mark --wet-until later)")
    out = [Setting(n, m, mode) for n in fitting for m in lags if 4 * m <= n for mode in modes]
    return sorted(out, key=lambda s: (abs(math.log(s.window / 100)) + abs(math.log(s.lag / 5)) / 2,
                                      s.mode != "sliding"))


def check_marks(run: Run) -> None:
    """The marks inside the run and in order; a DataError (exit 65) says what is wrong."""
    if not 0 < run.wet_until_s < run.dry_from_s < run.duration_s:
        raise DataError(f"{run.name}: the marks must satisfy 0 < --wet-until ({run.wet_until_s:g} s) < --dry-from "
                        f"({run.dry_from_s:g} s) < the run's end ({run.duration_s:g} s)")


def tune(run: Run, config: DaemonConfig, masks: dict[str, np.ndarray], budget_s: float,
         settings: Sequence[Setting], on_frame: Callable[[], None] | None = None,
         on_pass: Callable[[Setting, int, int], None] | None = None,
         estimators: Sequence[str] = DEFAULT_CANDIDATES) -> Result:
    """Score every candidate of ``estimators`` at ``settings`` on ``run`` within ``budget_s``
    (module docstring)."""
    check_marks(run)
    started = time.perf_counter()
    result = Result(run)
    step = max(1, round(STATE_STEP_S / run.dt), math.ceil(run.count / MAX_SAMPLES))
    dwell = {region.name: region.min_dwell_s for region in config.regions}
    sample = _cost_frames(run, config, masks)
    section = config.kinetics.model_copy(update={"enabled": True})  # the config's, or the daemon's defaults
    kinetics = KINETICS in estimators and bool(settings)
    if kinetics and (why := run.kinetics_problem()) is not None:
        result.excluded.append((Candidate(KINETICS, False, settings[0]), why))
        kinetics = False
    last_s = 0.0  # the last setting's time: pass, costs and scoring
    for index, setting in enumerate(settings):
        setting_started = time.perf_counter()
        if result.series and setting_started - started + last_s > budget_s:  # a setting costs about the last
            result.skipped = list(settings[index:])
            break
        if on_pass is not None:
            on_pass(setting, index, len(settings))
        series = run_pass(run.frames(), setting, config, masks, run.dt, step, bits=run.bits, times_s=run.times_s,
                          on_frame=on_frame, estimators=estimators,
                          kinetics=section if kinetics and index == 0 else None)
        result.series.append(series)
        if series.kinetics_read_s is not None:
            cost = _kinetics_cost(sample, section, config, masks, run.dt, series.kinetics_read_s)
            _score(result, Candidate(KINETICS, False, setting), series, run, dwell, cost)
        costs: dict[str, float] = {}
        for candidate in candidates(settings[:index + 1], estimators):
            if candidate.setting != setting:  # scored at an earlier setting
                continue
            if candidate.estimator not in costs:
                costs[candidate.estimator] = _cost(sample, candidate, series, run.bits, config.estimator.q)
            _score(result, candidate, series, run, dwell, costs[candidate.estimator])
        last_s = time.perf_counter() - setting_started
    result.chosen, result.reason = choose(result.outcomes)
    result.seconds = time.perf_counter() - started
    if result.chosen is None and max((o.auc for o in result.outcomes), default=0.0) < USABLE_AUC:
        raise DataError(f"{run.name}: {result.reason}")
    return result


def _score(result: Result, candidate: Candidate, series: Series, run: Run, dwell: dict[str, float],
           cost: float) -> None:
    outcome = evaluate(candidate, series, run.wet_until_s, run.dry_from_s, dwell, run.dt, cost)
    if isinstance(outcome, str):
        result.excluded.append((candidate, outcome))
    else:
        result.outcomes.append(outcome)


def skipped_states(outcome: Outcome) -> tuple[str, ...]:
    """The states of wet -> drying -> dry some region's replay of the reference run never shows
    before its dry call (scoring.Replay.skipped): the daemon with these thresholds skips them."""
    skipped = {state for region in outcome.regions.values() for state in region.replay.skipped}
    return tuple(state for state in ORDER if state in skipped)


def choose(outcomes: Sequence[Outcome]) -> tuple[Outcome | None, str]:
    """The recommendation among the outcomes whose replay shows every state (candidates.recommend):
    thresholds with which the daemon would skip a state are not proposed (they stay in the report,
    marked); the reason says how many were left out for it."""
    showing = [outcome for outcome in outcomes if not skipped_states(outcome)]
    left = [outcome for outcome in outcomes if outcome.sound and skipped_states(outcome)]
    if left and not pareto(showing):
        states = sorted({state for outcome in left for state in skipped_states(outcome)}, key=ORDER.index)
        return None, (f"no candidate shows wet, drying and dry in turn on this run: the {len(left)} that call it "
                      f"dry soundly would skip {' and '.join(states)} (the surface crosses their drying band "
                      "within regions.min_dwell_s: a shorter dwell, or a reference run of a slower drying)")
    chosen, reason = recommend(showing)
    if left:
        states = sorted({state for outcome in left for state in skipped_states(outcome)}, key=ORDER.index)
        reason += (f"; {len(left)} candidate{'s' if len(left) > 1 else ''} that would skip "
                   f"{' and '.join(states)} on this run {'are' if len(left) > 1 else 'is'} not proposed")
    return chosen, reason


def _cost_frames(run: Run, config: DaemonConfig, masks: dict[str, np.ndarray]) -> list[np.ndarray]:
    """A few frames of the run as the daemon's engine would see them."""
    frames = []
    for frame in run.frames():
        if config.estimator.area == "regions":
            rows, cols = bounding_box(list(masks.values()))
            frame = np.ascontiguousarray(frame[rows, cols])
        frames.append(np.array(frame))
        if len(frames) == COST_FRAMES:
            break
    return frames


def _cost(frames: list[np.ndarray], candidate: Candidate, series: Series, bits: int | None, q: float) -> float:
    """The candidate's estimator alone in the engine, at the q its daemon runs at (a map formed at
    q = 0, Fujii: 0)."""
    return push_cost(frames, (candidate.estimator,), candidate.setting, bits, max_lag=series.max_lag if
                     candidate.estimator == "tau_c" else None, q=registry.get(candidate.estimator).q_for(q))


def _kinetics_cost(frames: list[np.ndarray], section: KineticsSection, config: DaemonConfig,
                   masks: dict[str, np.ndarray], dt: float, read_s: float) -> float:
    """The kinetics' push of every region on the frames the daemon's pipeline pushes (cropped with
    ``area = "regions"``), plus a read at the states cadence shared over the frames between."""
    if config.estimator.area == "regions":
        rows, cols = bounding_box(list(masks.values()))
        masks = {name: mask[rows, cols] for name, mask in masks.items()}
    return kinetics_cost(frames, section, masks, dt) + read_s * min(1.0, dt / STATE_STEP_S)
