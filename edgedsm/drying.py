"""Drying-state machine per region (pure: no I/O, the clock is passed in).

States: ``warming_up`` (the estimator window is not full yet) → ``wet`` → ``drying`` → ``dry``,
and ``fault`` (no trustworthy data: camera lost, laser fault). The activity is a region's mean
of the chosen estimator (S1 grey levels, S2/S3 dimensionless). Thresholds:

- activity >= ``wet_above``  → wet;   activity <= ``dry_below`` → dry;   between → drying.
- Hysteresis: a state is left only when the activity crosses its threshold by the relative
  margin ``hysteresis`` (e.g. wet is left below wet_above·(1 − h), entered above
  wet_above·(1 + h)), so noise around a threshold does not make the state flicker.
- Dwell: a new state must hold for ``min_dwell_s`` seconds before the transition happens.
- A re-coated surface may go back up (dry → drying → wet); every transition is reported.

The time left until dry is extrapolated from an exponential fit (log-linear least squares) of
the activity over the last ``trend_window_s`` seconds.

A region may instead be judged on its correlation time τc in seconds (``Thresholds.of_tau``:
``wet_below_s`` / ``dry_above_s``): a wet surface decorrelates fast, so τc *rises* as it dries.
The machine then judges the decorrelation rate 1/τc (1/s), which falls as it dries like any
activity, so the hysteresis (relative: leaving wet at τc > wet_below_s/(1 - h)), the dwell and
the time to dry (an exponential trend of 1/τc is one of τc) stay the same logic; what it
reports (``activity``, the transitions) is τc in seconds, as configured.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from edgedsm.config.thresholds import Thresholds

__all__ = ["DryingMonitor", "DryingState", "RegionStateMachine", "Thresholds", "Transition"]


class DryingState(StrEnum):
    WARMING_UP = "warming_up"
    WET = "wet"
    DRYING = "drying"
    DRY = "dry"
    FAULT = "fault"


@dataclass(frozen=True)
class Transition:
    """One state change: the alert the daemon publishes."""

    region: str
    from_state: DryingState
    to_state: DryingState
    activity: float | None
    t: float
    reason: str

    def as_dict(self) -> dict:
        return {"type": "transition", "region": self.region, "from": str(self.from_state),
                "to": str(self.to_state), "activity": self.activity, "t": self.t, "reason": self.reason}


class RegionStateMachine:
    """The drying state of one region."""

    def __init__(self, region: str, thresholds: Thresholds, t0: float = 0.0) -> None:
        self.region = region
        self.thresholds = thresholds
        self.state = DryingState.WARMING_UP
        self.since = t0
        self.activity: float | None = None
        self._candidate: DryingState | None = None
        self._candidate_since = t0
        self._history: deque[tuple[float, float]] = deque()

    def _classify(self, activity: float) -> DryingState:
        th, h, state = self.thresholds, self.thresholds.hysteresis, self.state
        wet_in, wet_out = th.wet_above * (1 + h), th.wet_above * (1 - h)
        dry_in, dry_out = th.dry_below * (1 - h), th.dry_below * (1 + h)
        if state not in (DryingState.WET, DryingState.DRYING, DryingState.DRY):
            h = 0.0  # first classification after warm-up or a fault: plain thresholds
            wet_in = wet_out = th.wet_above
            dry_in = dry_out = th.dry_below
        if state == DryingState.WET:
            if activity >= wet_out:
                return DryingState.WET
            return DryingState.DRY if activity <= dry_in else DryingState.DRYING
        if state == DryingState.DRY:
            if activity <= dry_out:
                return DryingState.DRY
            return DryingState.WET if activity >= wet_in else DryingState.DRYING
        if activity >= wet_in:
            return DryingState.WET
        if activity <= dry_in:
            return DryingState.DRY
        return DryingState.DRYING

    def step(self, t: float, activity: float | None, ready: bool = True, fault: str | None = None) -> Transition | None:
        """Feed one observation at time ``t`` (s); returns the transition it caused, if any.

        ``ready`` False means the estimator window is not full; ``fault`` names a fault.
        """
        if fault is not None:
            self._candidate = None
            return self._move(DryingState.FAULT, t, activity, fault) if self.state != DryingState.FAULT else None
        if ready and activity is not None and not math.isfinite(activity):
            raise ValueError(f"activity must be finite, got {activity}")
        value, judged = activity, self.thresholds.activity_of(activity)  # on_tau: τc (s) and 1/τc
        if not ready or judged is None:
            if self.state == DryingState.FAULT:
                return self._move(DryingState.WARMING_UP, t, value, "fault cleared, waiting for data")
            return None
        self.activity = value
        self._remember(t, judged)
        if self.state in (DryingState.WARMING_UP, DryingState.FAULT):
            return self._move(self._classify(judged), t, value, "window full")
        target = self._classify(judged)
        if target == self.state:
            self._candidate = None
            return None
        if target != self._candidate:
            self._candidate, self._candidate_since = target, t
        if t - self._candidate_since >= self.thresholds.min_dwell_s:
            what = f"τc {value:.4g} s" if self.thresholds.on_tau else f"activity {value:.4g}"
            return self._move(target, t, value, f"{what} held for {t - self._candidate_since:.1f} s")
        return None

    def reset(self, t: float, reason: str) -> Transition | None:
        """Start over (new baseline, new burst): back to warming up, reported if it is a change."""
        self._history.clear()
        self._candidate = None
        if self.state == DryingState.WARMING_UP:
            return None
        return self._move(DryingState.WARMING_UP, t, None, reason)

    def _move(self, to: DryingState, t: float, activity: float | None, reason: str) -> Transition:
        transition = Transition(self.region, self.state, to, activity, t, reason)
        self.state, self.since, self._candidate = to, t, None
        return transition

    def _remember(self, t: float, activity: float) -> None:
        self._history.append((t, activity))
        while self._history and self._history[0][0] < t - self.thresholds.trend_window_s:
            self._history.popleft()

    def time_to_dry(self) -> float | None:
        """Seconds until the activity falls to ``dry_below`` (on τc: until τc reaches
        ``dry_above_s``) at the recent exponential trend.

        0 when dry; None when unknown (too little data, activity not falling, or not positive).
        """
        if self.state == DryingState.DRY:
            return 0.0
        if self.state not in (DryingState.WET, DryingState.DRYING) or len(self._history) < 3:
            return None
        times = np.array([p[0] for p in self._history])
        values = np.array([p[1] for p in self._history])
        if (values <= 0).any() or times[-1] - times[0] <= 0:
            return None
        slope, intercept = np.polyfit(times - times[-1], np.log(values), 1)
        if slope * (times[-1] - times[0]) > -1e-6:  # flat within rounding: no trend to extrapolate
            return None
        remaining = (math.log(self.thresholds.dry_below) - intercept) / slope
        return max(0.0, float(remaining))

    def snapshot(self) -> dict:
        """The region's state as published (retained) by the daemon."""
        return {"state": str(self.state), "since": self.since, "activity": self.activity,
                "time_to_dry_s": self.time_to_dry()}


class DryingMonitor:
    """State machines of all regions, stepped together."""

    def __init__(self, thresholds: dict[str, Thresholds], t0: float = 0.0) -> None:
        self.regions = {name: RegionStateMachine(name, th, t0) for name, th in thresholds.items()}

    def step(self, t: float, activities: dict[str, float], ready: bool = True,
             fault: str | None = None) -> list[Transition]:
        transitions = []
        for name, machine in self.regions.items():
            transition = machine.step(t, activities.get(name), ready, fault)
            if transition is not None:
                transitions.append(transition)
        return transitions

    def reset(self, t: float, reason: str) -> list[Transition]:
        return [tr for machine in self.regions.values() if (tr := machine.reset(t, reason)) is not None]

    def snapshot(self) -> dict[str, dict]:
        return {name: machine.snapshot() for name, machine in self.regions.items()}
