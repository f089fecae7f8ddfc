"""Drying stages from the kinetics (issue 37, part 4): per region, the time at which its speckle
rate 1/τ falls to each of the plant's stage thresholds (``[kinetics] stages``: set-to-touch,
tack-free, dry-hard in ASTM D5895's sense, the plant's own numbers), and the time to the next
stage from the rate's trend. Pure: readings and times in, stages reached and estimates out; the
daemon's evaluator publishes them (alerts of kind ``stage``, the stats' ``kinetics``).

A stage is reached when the rate stays at or below its threshold for ``stage_dwell_s`` (τ scatters
about 10 % from frame to frame, docs/kinetics.md); the time reported is the first reading of that
run, the crossing. A reading ``above`` the longest age bounds the rate from above (rate < 1/bound):
it counts as at or below a threshold the bound is past; ``below`` (rate > 1 per frame) as above
every threshold; a reading without a number (dark, saturated, not speckle, warming up) neither
extends nor breaks a run. Stages are reached in order and kept (a film does not get wet again: a
rebaseline starts over).

The trend: a least-squares line through ln(rate) against time over the last ``trend_window_s``
(a film's rate falls roughly exponentially in time between stages: the exponential law of
``[activity.drying]``); the time to the next stage is where that line reaches its threshold, None
while the line does not fall or fewer than TREND_MIN readings span it.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from edgedsm.config.kinetics import KineticsSection
from edgedsm.estimators.kinetics import ABOVE, BELOW, OK
from edgedsm.messages import RegionKinetics

#: Readings a trend needs before it estimates a time to the next stage.
TREND_MIN = 5


@dataclass(frozen=True)
class StageReached:
    """A region reached ``stage`` at ``t`` (the tracker's clock, s) with its rate then (Hz; for a
    reading above the longest age, the bound's rate, an upper bound)."""

    region: str
    stage: str
    t: float
    rate_hz: float
    threshold_hz: float

    def reason(self) -> str:
        return (f"drying stage {self.stage} reached: speckle rate {self.rate_hz:.4g} Hz at or below "
                f"{self.threshold_hz:.4g} Hz (τ {1.0 / self.rate_hz:.4g} s)")


def rate_bound(reading: RegionKinetics) -> tuple[float, bool] | None:
    """(rate in Hz, exact) of a reading: the measured rate; for ``above`` the rate of its bound,
    an upper bound (exact False); for ``below`` +inf; None without a number."""
    if reading.status == OK and reading.rate_hz is not None:
        return reading.rate_hz, True
    if reading.status == ABOVE and reading.bound_s is not None:
        return 1.0 / reading.bound_s, False
    if reading.status == BELOW:
        return math.inf, False
    return None


class StageTracker:
    """One region's stages (``stages``: (name, rate threshold in Hz), falling) and its trend."""

    def __init__(self, region: str, stages: tuple[tuple[str, float], ...], dwell_s: float,
                 trend_window_s: float) -> None:
        self.region = region
        self.stages = stages
        self.dwell_s = dwell_s
        self.trend_window_s = trend_window_s
        self.reached: dict[str, float] = {}  # stage -> when (s, the caller's clock)
        self._since: dict[str, float] = {}  # stage -> first reading of its current run at or below it
        self._trend: deque[tuple[float, float]] = deque()  # (t, ln rate) of exact readings

    @property
    def next_stage(self) -> tuple[str, float] | None:
        """The next stage not yet reached and its threshold (Hz); None when all are."""
        return self.stages[len(self.reached)] if len(self.reached) < len(self.stages) else None

    def step(self, now: float, reading: RegionKinetics) -> list[StageReached]:
        """Take one reading at ``now`` (s); the stages reached by it (a reading may complete more
        than one: a film past two thresholds within the dwell)."""
        rate = rate_bound(reading)
        if rate is None:
            return []
        value, exact = rate
        if exact and value > 0:
            self._trend.append((now, math.log(value)))
        while self._trend and now - self._trend[0][0] > self.trend_window_s:
            self._trend.popleft()
        for name, threshold in self.stages:  # each stage's run: from the first reading at or below it
            if name in self.reached:
                continue
            if value > threshold:
                self._since.pop(name, None)
            else:
                self._since.setdefault(name, now)
        out = []
        while (stage := self.next_stage) is not None:  # in order: a stage after the ones before it
            name, threshold = stage
            since = self._since.get(name)
            if since is None or now - since < self.dwell_s:
                break
            self.reached[name] = since
            del self._since[name]
            out.append(StageReached(self.region, name, since, value, threshold))
        return out

    def time_to_next_s(self, now: float) -> float | None:
        """Seconds from ``now`` until the trend line of ln rate reaches the next stage's threshold
        (0 when already at or below it; None: no next stage, too few readings, or no fall)."""
        stage = self.next_stage
        if stage is None or len(self._trend) < TREND_MIN:
            return None
        times, logs = np.array(self._trend).T
        if times[-1] - times[0] <= 0:
            return None
        slope, intercept = np.polyfit(times - times[-1], logs, 1)
        if not slope < 0:
            return None
        target = math.log(stage[1])
        at_now = intercept + slope * (now - times[-1])
        return max(0.0, (target - at_now) / slope)

    def reset(self) -> None:
        self.reached.clear()
        self._since.clear()
        self._trend.clear()


class KineticsStages:
    """Every region's :class:`StageTracker` from ``[kinetics]`` (one thread: the evaluator's)."""

    def __init__(self, section: KineticsSection, regions: tuple[str, ...] | list[str]) -> None:
        stages = tuple((stage.name, stage.rate_below_hz) for stage in section.stages)
        self.trackers = {name: StageTracker(name, stages, section.stage_dwell_s, section.trend_window_s)
                         for name in regions}
        self.on = bool(stages)

    def step(self, now: float, readings: Mapping[str, RegionKinetics], to_wall: Callable[[float], float]
             ) -> tuple[dict[str, RegionKinetics], list[StageReached]]:
        """Each region's reading with its stages (when reached, on the wall clock), the next stage
        and the time to it; the stages reached by these readings."""
        if not self.on:
            return dict(readings), []
        out, reached = {}, []
        for name, reading in readings.items():
            tracker = self.trackers.get(name)
            if tracker is None:
                out[name] = reading
                continue
            reached += tracker.step(now, reading)
            stage = tracker.next_stage
            out[name] = reading.model_copy(update={
                "stages": {stage_name: to_wall(t) for stage_name, t in tracker.reached.items()},
                "next_stage": None if stage is None else stage[0],
                "time_to_next_stage_s": tracker.time_to_next_s(now)})
        return out, reached

    def reset(self) -> None:
        for tracker in self.trackers.values():
            tracker.reset()


#: ``analyze --timeline --kinetics -c CONFIG`` with ``[[kinetics.stages]]``: per region and sample the
#: last stage reached ("none" before the first), when it was reached (s, the timeline's clock), the
#: next stage ("none" once all are) and the time to it from the rate's trend (s; NaN: no trend yet).
COLUMNS = ("kinetics_stage", "kinetics_stage_at_s", "kinetics_next_stage", "kinetics_time_to_next_s")


def cells(reading: RegionKinetics | None) -> tuple[str, float, str, float]:
    """A reading stepped through :class:`KineticsStages` as :data:`COLUMNS`."""
    if reading is None:
        return ("none", math.nan, "none", math.nan)
    last = next(reversed(reading.stages), None)  # stages are reached, and kept, in order
    return ("none" if last is None else last, math.nan if last is None else reading.stages[last],
            reading.next_stage or "none",
            math.nan if reading.time_to_next_stage_s is None else reading.time_to_next_stage_s)
