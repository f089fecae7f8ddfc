"""Drying stages from the kinetics (edgedsm.measurement.stages; issue 37 part 4): the time each
stage's rate threshold is crossed (held stage_dwell_s), in order; bounds and dark readings; the
time to the next stage from the rate's trend."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edgedsm.config import DaemonConfig
from edgedsm.config.kinetics import KineticsSection
from edgedsm.errors import ConfigError
from edgedsm.measurement.stages import KineticsStages, StageTracker, rate_bound
from edgedsm.messages import RegionKinetics
from edgedsm.validation import validate

STAGES = (("touch", 1.0), ("tack_free", 0.1), ("hard", 0.01))


def ok(rate: float) -> RegionKinetics:
    return RegionKinetics(status="ok", tau_s=1.0 / rate, rate_hz=rate)


def test_an_exponentially_falling_rate_reaches_each_stage_at_its_crossing() -> None:
    # rate = 10 Hz · exp(-t/100 s): crosses 1 Hz at 230.3 s, 0.1 Hz at 460.5 s, 0.01 Hz at 690.8 s
    tracker = StageTracker("plate", STAGES, dwell_s=10.0, trend_window_s=60.0)
    reached = []
    estimates = {}
    for t in np.arange(0.0, 800.0, 0.5):
        reached += tracker.step(float(t), ok(10.0 * math.exp(-t / 100.0)))
        if t in (300.0, 600.0):
            estimates[t] = tracker.time_to_next_s(float(t))
    assert [r.stage for r in reached] == ["touch", "tack_free", "hard"]
    for r, crossing in zip(reached, (230.26, 460.52, 690.78), strict=True):
        assert r.t == pytest.approx(crossing, abs=0.5) and tracker.reached[r.stage] == r.t
    assert "tack_free" in reached[1].reason() and "0.1 Hz" in reached[1].reason()
    # the trend: from 300 s the next (0.1 Hz) is 160.5 s away, from 600 s the next (0.01 Hz) 90.8 s
    assert estimates[300.0] == pytest.approx(160.5, rel=0.01) and estimates[600.0] == pytest.approx(90.8, rel=0.01)
    assert tracker.next_stage is None and tracker.time_to_next_s(800.0) is None


def test_the_dwell_ignores_a_flicker_and_dark_readings_hold_the_run() -> None:
    tracker = StageTracker("plate", STAGES[:1], dwell_s=5.0, trend_window_s=60.0)
    assert tracker.step(0.0, ok(0.9)) == [] and tracker.step(3.0, ok(1.2)) == []  # back above: run broken
    assert tracker.step(4.0, ok(0.9)) == [] and tracker.step(6.0, RegionKinetics(status="dark")) == []
    assert tracker.step(8.0, ok(0.95)) == []  # 4 s into the run
    reached = tracker.step(9.0, ok(0.95))
    assert [(r.stage, r.t) for r in reached] == [("touch", 4.0)]  # at the run's first reading
    assert tracker.time_to_next_s(9.0) is None  # no next stage


def test_bounds_count_as_what_they_bound() -> None:
    assert rate_bound(RegionKinetics(status="above", bound_s=50.0)) == (0.02, False)
    assert rate_bound(RegionKinetics(status="below", bound_s=0.05)) == (math.inf, False)
    assert rate_bound(RegionKinetics(status="not_speckle")) is None
    tracker = StageTracker("plate", STAGES, dwell_s=0.0, trend_window_s=60.0)
    reached = tracker.step(1.0, RegionKinetics(status="above", bound_s=50.0))  # rate < 0.02 Hz: two stages
    assert [r.stage for r in reached] == ["touch", "tack_free"] and tracker.next_stage == ("hard", 0.01)
    assert tracker.time_to_next_s(1.0) is None  # bounds make no trend
    tracker.reset()
    assert tracker.reached == {} and tracker.step(2.0, RegionKinetics(status="below", bound_s=0.05)) == []


def test_every_region_s_reading_carries_its_stages_on_the_wall_clock() -> None:
    section = KineticsSection(enabled=True, longest_age_s=3600.0, stage_dwell_s=0.0,
                              stages=[{"name": "touch", "rate_below_hz": 1.0}])
    stages = KineticsStages(section, ["a", "b"])
    out, reached = stages.step(10.0, {"a": ok(0.5), "b": ok(2.0)}, lambda t: 1000.0 + t)
    assert [r.region for r in reached] == ["a"]
    assert out["a"].stages == {"touch": 1010.0} and out["a"].next_stage is None
    assert out["b"].stages == {} and out["b"].next_stage == "touch" and out["b"].time_to_next_stage_s is None
    plain = KineticsStages(KineticsSection(), ["a"])
    assert plain.step(1.0, {"a": ok(0.5)}, float)[0]["a"].next_stage is None  # no stages configured


@pytest.mark.parametrize(("stages", "message"), [
    ([{"name": "a", "rate_below_hz": 0.1}, {"name": "b", "rate_below_hz": 1.0}],
     "stages.1.rate_below_hz: 1 Hz is not below the stage before's 0.1 Hz"),
    ([{"name": "a", "rate_below_hz": 1.0}, {"name": "a", "rate_below_hz": 0.1}], "names must be unique"),
    ([{"name": "a", "rate_below_hz": 0.0001}], "stages.0.rate_below_hz: τ = 1/0.0001 Hz = 1e+04 s is not below"),
    ([{"name": "a b", "rate_below_hz": 1.0}], "kinetics.stages.0.name: String should match pattern"),
])
def test_bad_stages_are_refused_with_the_key(stages: list, message: str) -> None:
    with pytest.raises(ConfigError, match=message.replace("(", r"\(").replace("+", r"\+")):
        validate(DaemonConfig,
                 {"camera": {"uri": "sim:default"}, "kinetics": {"enabled": True, "stages": stages}}, "<stages>")
