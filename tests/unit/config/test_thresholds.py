"""A region's drying thresholds as a value (edgedsm/config/thresholds.py): its checks, the τc form,
and the one value [[regions]] builds and the drying machine judges with."""

from __future__ import annotations

import pytest

from edgedsm import drying
from edgedsm.config.regions import RectArea
from edgedsm.config.thresholds import Thresholds


@pytest.mark.parametrize("kw", [{"wet_above": 1, "dry_below": 2}, {"hysteresis": 0.6},
                                {"wet_above": 2.1, "dry_below": 2.0, "hysteresis": 0.1}, {"min_dwell_s": -1},
                                {"trend_window_s": 0}, {"wet_above": float("inf")}])
def test_bad_thresholds_are_refused(kw):
    params = {"wet_above": 10.0, "dry_below": 2.0} | kw
    with pytest.raises(ValueError):
        Thresholds(**params)


def test_thresholds_on_tau_are_rates_and_judge_the_rate() -> None:
    th = Thresholds.of_tau(wet_below_s=0.2, dry_above_s=0.5, hysteresis=0.1, min_dwell_s=3.0)
    assert (th.wet_above, th.dry_below, th.on_tau) == (pytest.approx(5.0), pytest.approx(2.0), True)
    assert th.activity_of(0.25) == pytest.approx(4.0) and th.activity_of(0.0) is None
    assert Thresholds(10.0, 2.0).activity_of(0.25) == 0.25
    with pytest.raises(ValueError, match="wet_below_s"):
        Thresholds.of_tau(wet_below_s=0.5, dry_above_s=0.2)
    with pytest.raises(ValueError, match="overlap"):  # the bands in τc's words
        Thresholds.of_tau(wet_below_s=0.2, dry_above_s=0.21, hysteresis=0.1)


def test_the_section_builds_the_value_the_machine_judges_with() -> None:
    section = RectArea(shape="rect", name="plate", x=0, y=0, width=4, height=4, wet_above=3.0, dry_below=1.0,
                       hysteresis=0.1, min_dwell_s=0.0, trend_window_s=60.0)
    assert section.thresholds() == Thresholds(3.0, 1.0, 0.1, 0.0, 60.0)
    assert drying.Thresholds is Thresholds  # one definition: the machine takes the config's value
    machine = drying.RegionStateMachine("plate", section.thresholds())
    machine.step(0.0, 4.0)
    assert machine.state == drying.DryingState.WET
