"""How well one activity series tells wet from dry, the thresholds it proposes, and what the
drying state machine does with them (docs/commissioning.md). Pure: arrays in, dataclasses out.

Every series is an *activity*: large when wet, small when dry (S1, S2, S3 and the descriptors
as they are; τc as its rate 1/τc, as :class:`~edgedsm.drying.Thresholds` judges it). Times are
seconds from the first frame of the run.

- Separation: the AUC, P(a wet sample > a dry sample) (Mann-Whitney U / (n_w n_d), ties half),
  and d′ = (mean_w - mean_d) / sqrt((var_w + var_d)/2), both on the log of the activity (levels
  spread multiplicatively; zero and negative values, above-noise activity within the noise, are
  clipped to the smallest positive one).
- Thresholds: between the wet samples' 5th percentile and the dry samples' 95th, at one and two
  thirds of the gap in log (dry_below, wet_above), so that hysteresis bands fit; when the two
  overlap, around the geometric mean of the medians, and the state machine's replay judges them.
- Replay: the measurement core's state machine (:func:`edgedsm.measurement.core.step_states`, as
  the daemon's evaluator steps it) through the series with the proposed thresholds, hysteresis and
  dwell: the delay is the time from the
  first transition into ``dry`` after the wet mark to the dry mark (negative: called dry before
  the mark, which the marks allow: between them the state is not known); a false transition
  is one on a flat part (before the wet mark: any move to a state other than wet) or any move
  back towards wet (which includes leaving dry); a state of wet → drying → dry the replay never
  shows before its first dry call is *skipped* (a drying band crossed within the dwell: the daemon
  on a like run would skip it too, and a line waiting for ``drying`` would never see it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from edgedsm.drying import DryingMonitor, DryingState, Thresholds
from edgedsm.errors import EstimatorError
from edgedsm.measurement.core import step_states

WET_QUANTILE, DRY_QUANTILE = 5.0, 95.0  # percentiles bounding the gap the thresholds are put in
HYSTERESIS = 0.05  # the daemon's default
#: the log gap between the percentiles the thresholds split in thirds: the middle third must hold
#: the hysteresis bands, log((1 + h)/(1 - h)), with half as much again to spare
MIN_LOG_GAP = 4.5 * math.log((1 + HYSTERESIS) / (1 - HYSTERESIS))
ORDER = ("wet", "drying", "dry")  # the states a drying surface shows, in order
_BACKWARD = {(DryingState.DRY, DryingState.DRYING), (DryingState.DRY, DryingState.WET),
             (DryingState.DRYING, DryingState.WET)}


@dataclass(frozen=True)
class Separation:
    auc: float  # P(wet > dry), 0.5: no separation, 1: complete
    d_prime: float  # in pooled standard deviations of the log activity
    wet_samples: int
    dry_samples: int


@dataclass(frozen=True)
class Replay:
    """What the state machine did on the run with the proposed thresholds."""

    states: list[tuple[float, str, str]]  # (t, from, to) of every transition
    delay_s: float | None  # dry call after the dry mark, negative if before it (None: never called dry)
    false_transitions: int
    flat_s: float  # seconds of flat parts (wet before the wet mark, dry after the dry call)
    skipped: tuple[str, ...] = ()  # states of wet -> drying -> dry not shown before the first dry call

    @property
    def false_per_hour(self) -> float:
        return self.false_transitions * 3600.0 / self.flat_s if self.flat_s > 0 else float(self.false_transitions)


def _positive(values: np.ndarray) -> np.ndarray:
    finite = np.asarray(values, np.float64)
    finite = finite[np.isfinite(finite)]
    floor = finite[finite > 0].min() if (finite > 0).any() else 1e-12
    return np.maximum(finite, floor)


def separation(wet: np.ndarray, dry: np.ndarray) -> Separation:
    """AUC and d′ of the wet against the dry samples of one activity series (module docstring)."""
    w, d = np.log(_positive(wet)), np.log(_positive(dry))
    if w.size == 0 or d.size == 0:
        raise EstimatorError(f"no {'wet' if w.size == 0 else 'dry'} samples to compare")
    both = np.concatenate([w, d])
    order = np.argsort(both, kind="stable")
    sorted_values = both[order]
    # 0-based ranks, averaged over ties (Mann-Whitney)
    starts = np.flatnonzero(np.r_[True, np.diff(sorted_values) != 0])
    ends = np.r_[starts[1:], sorted_values.size]
    average = np.empty(both.size)
    for start, end in zip(starts, ends, strict=True):
        average[order[start:end]] = (start + end - 1) / 2.0
    u = float(average[:w.size].sum() - w.size * (w.size - 1) / 2.0)
    auc = u / (w.size * d.size)
    pooled = math.sqrt((float(w.var()) + float(d.var())) / 2.0)
    gap = float(w.mean() - d.mean())
    d_prime = gap / pooled if pooled > 0 else (math.inf if gap > 0 else 0.0)
    return Separation(auc, d_prime, int(w.size), int(d.size))


def propose(wet: np.ndarray, dry: np.ndarray, on_tau: bool = False, min_dwell_s: float = 5.0,
            hysteresis: float = HYSTERESIS, most: float | None = None) -> Thresholds:
    """Thresholds between the wet and the dry samples (module docstring); ``on_tau``: the series
    are rates 1/τc and the thresholds are returned as :meth:`Thresholds.of_tau` would make them.
    ``most``: the largest dry threshold the estimator can show (τc: its rate at K·Δt, the longest
    lag; a dry call needs τc to reach it)."""
    w, d = _positive(wet), _positive(dry)
    high, low = float(np.percentile(w, WET_QUANTILE)), float(np.percentile(d, DRY_QUANTILE))
    if high <= low * math.exp(MIN_LOG_GAP):  # overlapping or too close: around the medians' mean
        centre = math.sqrt(float(np.median(w)) * float(np.median(d)))
        half = math.exp(MIN_LOG_GAP / 2.0)
        high, low = centre * half * half, centre / (half * half)
        if high <= 0 or low <= 0 or not math.isfinite(high):
            raise EstimatorError("the wet and dry samples give no threshold")
    ratio = math.log(high / low)
    dry_below, wet_above = low * math.exp(ratio / 3.0), low * math.exp(2.0 * ratio / 3.0)
    if most is not None:
        # a rate: the dry threshold must be reachable, dry_below·(1-h) >= the rate at the longest lag
        dry_below = max(dry_below, most / (1.0 - hysteresis) * 1.001)
        wet_above = max(wet_above, dry_below * (1.0 + hysteresis) / (1.0 - hysteresis) * 1.01)
    return Thresholds(wet_above, dry_below, hysteresis, min_dwell_s, on_tau=on_tau)


def replay(times: np.ndarray, activity: np.ndarray, thresholds: Thresholds, wet_until_s: float,
           dry_from_s: float) -> Replay:
    """Step the state machine through the series (``activity`` as the daemon judges it: τc in
    seconds when the thresholds are on τc, NaN: held) and score it (module docstring)."""
    t = np.asarray(times, np.float64)
    values = np.asarray(activity, np.float64)
    if t.shape != values.shape or t.ndim != 1 or t.size == 0:
        raise EstimatorError("times and activity must be two 1-D arrays of the same length")
    monitor = DryingMonitor({"r": thresholds}, t0=float(t[0]))
    path: list[str] = []  # the states entered up to the first dry call after the wet mark
    states: list[tuple[float, str, str]] = []
    false = 0
    dry_at: float | None = None
    for when, value in zip(t, values, strict=True):
        observed = float(value) if math.isfinite(value) else None
        for transition in step_states(monitor, float(when), {"r": observed}):
            states.append((float(when), str(transition.from_state), str(transition.to_state)))
            move = (transition.from_state, transition.to_state)
            wrong = move in _BACKWARD or (when <= wet_until_s and transition.to_state != DryingState.WET)
            false += bool(wrong)
            if dry_at is None:
                path.append(str(transition.to_state))
            if transition.to_state == DryingState.DRY and dry_at is None and when > wet_until_s:
                dry_at = float(when)
    start = float(t[0])
    flat = max(0.0, min(wet_until_s, float(t[-1])) - start) + (max(0.0, float(t[-1]) - dry_at) if dry_at else 0.0)
    skipped = tuple(state for state in ORDER if state not in path) if dry_at is not None else ()
    return Replay(states, None if dry_at is None else dry_at - dry_from_s, false, flat, skipped)
