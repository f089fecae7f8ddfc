"""The fan-out's stop notice and the log sink's levels (edgedsm.publish.sink)."""

from __future__ import annotations

import logging
import time

import pytest

from edgedsm.messages import Alert, AlertKind, RegionState, StateReport
from edgedsm.publish.sink import FanOut, LogSink, RecordingSink


class Stopping(RecordingSink):
    def __init__(self, fail: bool = False) -> None:
        super().__init__()
        self.fail = fail
        self.told: list[tuple[str, float]] = []

    def stopping(self, laser: str, t: float) -> None:
        if self.fail:
            raise RuntimeError("broken")
        self.told.append((laser, t))


def test_the_stop_notice_reaches_every_sink_that_takes_it_even_past_a_failing_one() -> None:
    failing, plain, taking = Stopping(fail=True), RecordingSink(), Stopping()
    before = time.time()
    FanOut([failing, plain, taking]).stopping("unknown")
    assert [laser for laser, _ in taking.told] == ["unknown"] and before <= taking.told[0][1] <= time.time()


def test_the_last_word_is_offline_with_the_laser_as_confirmed_and_no_time_to_dry() -> None:
    report = StateReport(t=10.0, estimator="s2", laser="on", regions={
        "plate": RegionState(region="plate", state="drying", since=4.0, activity=0.125, plain=0.25,
                             time_to_dry_s=240.0)})
    final = report.stopped(12.5, "off")
    assert final.to_json() == {"t": 12.5, "estimator": "s2", "laser": "off", "availability": "offline",
                               "regions": {"plate": {"region": "plate", "state": "drying", "since": 4.0,
                                                     "activity": 0.125, "plain": 0.25, "time_to_dry_s": None}}}
    assert final.moved_from(report) and report.availability == "online"


@pytest.mark.parametrize(("alert", "level"), [
    (Alert(kind=AlertKind.TRANSITION, t=1.0, region="plate", from_state="wet", to_state="drying"), logging.INFO),
    (Alert(kind=AlertKind.RESET, t=1.0, reason="rebaseline"), logging.INFO),
    (Alert(kind=AlertKind.TRANSITION, t=1.0, region="plate", from_state="dry", to_state="fault"), logging.WARNING),
    (Alert(kind=AlertKind.FAULT, t=1.0, reason="camera lost"), logging.WARNING),
    (Alert(kind=AlertKind.WARNING, t=1.0, reason="signal dark"), logging.WARNING),
])
def test_a_normal_transition_is_logged_at_info_and_an_alert_at_warning(caplog: pytest.LogCaptureFixture,
                                                                        alert: Alert, level: int) -> None:
    with caplog.at_level(logging.DEBUG, logger="edgedsm.publish.sink"):
        LogSink().publish_alert(alert)
    assert [(record.levelno, record.getMessage()) for record in caplog.records] == [
        (level, f"alert: {alert.describe()}")]
