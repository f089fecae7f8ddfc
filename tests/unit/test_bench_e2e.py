"""The end-to-end benchmark's bookkeeping: the zero-drop rate search and the latency split
(pure parts only; the benchmark itself prints tables and is not run here)."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from edgedsm.bench.e2e import Trial, best_zero_drop, latency_parts, search_rate


def _trial(rate: float, drops: int) -> Trial:
    return Trial("paced", rate, 16, 5.0, 10.0, int(rate * 10), int(rate * 10), drops, 1.0, 100.0)


@pytest.mark.parametrize(("limit", "rates", "best"), [
    (82.0, [60, 180, 120, 90, 75, 80], 80),  # up by bisection towards the capacity (300), then down
    (50.0, [60, 30, 45, 50], 50),            # the target drops: bisect below it
    (10.0, [60, 30, 15, 10], 10),
    (5.0, [60, 30, 15, 10], None),           # nothing sustained down to a 10 frames/s bracket
    (1e9, [60, 180, 240, 270, 285, 290], 290),  # never drops: stops at the trial budget
])
def test_search_rate_finds_the_highest_sustained_rate(limit: float, rates: list[float], best: float | None) -> None:
    tried: list[float] = []

    def run(rate: float) -> Trial:
        tried.append(rate)
        return _trial(rate, 0 if rate <= limit else 3)

    trials = search_rate(run, start=60.0, ceiling=300.0, max_trials=6, resolution=10.0)
    assert tried == rates
    found = best_zero_drop(trials)
    assert (found.rate if found else None) == best


def test_a_source_that_cannot_keep_pace_is_not_sustained() -> None:
    trial = _trial(100.0, 0)
    assert trial.sustained
    trial.delivered = 900  # 90 frames/s delivered of 100 asked
    assert not trial.sustained and best_zero_drop([trial]) is None


def test_search_rate_respects_the_trial_budget() -> None:
    trials = search_rate(lambda rate: _trial(rate, 0), start=60.0, ceiling=300.0, max_trials=2)
    assert [t.rate for t in trials] == [60, 180]


def test_latency_parts_attributes_each_frame_to_the_first_stats_message_that_counts_it() -> None:
    # 10 frames, one every 0.1 s; each waits 0.01 s in the queue and 0.02 s in the push; the
    # window fills at frame 2; stats counting 3, 6 and 9 frames are published at 0.35, 0.65,
    # 0.95 s and arrive 5 ms later.
    seqs = list(range(100, 110))
    enqueued = {seq: 0.1 * i for i, seq in enumerate(seqs)}
    pushed = {seq: t + 0.03 for seq, t in enqueued.items()}
    pipeline = SimpleNamespace(ready_at=2, dequeued=seqs, enqueued=enqueued, pushed=pushed)
    sent = [(0.35, 3), (0.65, 6), (0.95, 9)]
    arrivals = [(t + 0.005, frames) for t, frames in sent]
    parts = latency_parts(pipeline, sent, arrivals)  # type: ignore[arg-type]
    # frames 4..9 count (those after the first stats message following the window's filling)
    totals = sorted(arrivals[1 + (i - 3) // 3][0] - enqueued[seqs[i]] for i in range(3, 9))
    assert parts["total"][0] == pytest.approx(sorted(totals)[2] + (sorted(totals)[3] - sorted(totals)[2]) / 2)
    assert parts["queue+push"] == pytest.approx((0.03, 0.03))
    assert parts["broker"] == pytest.approx((0.005, 0.005))
    assert parts["total"][1] == pytest.approx(max(totals), abs=0.01)
    assert parts["total"][1] <= max(totals)
