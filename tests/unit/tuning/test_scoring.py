"""Scoring a candidate's activity series (edgedsm.tuning.scoring): separation, thresholds, the
state machine replayed; and the choice among candidates (edgedsm.tuning.candidates)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from edgedsm.drying import Thresholds
from edgedsm.errors import EstimatorError
from edgedsm.tuning.candidates import Candidate, Outcome, RegionOutcome, candidates, pareto, recommend
from edgedsm.tuning.scoring import HYSTERESIS, Replay, Separation, propose, replay, separation
from edgedsm.tuning.series import Setting
from edgedsm.tuning.session import choose, skipped_states


def test_separation_is_mann_whitney_with_ties_and_d_prime_on_logs():
    wet, dry = np.array([3.0, 4.0, 5.0]), np.array([1.0, 2.0, 3.0])
    result = separation(wet, dry)
    assert result.auc == pytest.approx(8.5 / 9)  # 8 pairs wet > dry, one tie counted half
    w, d = np.log(wet), np.log(dry)
    assert result.d_prime == pytest.approx((w.mean() - d.mean()) / math.sqrt((w.var() + d.var()) / 2))
    assert separation(dry, wet).auc == pytest.approx(0.5 / 9)
    assert separation(np.array([0.0, -1.0, 2.0]), np.array([0.5])).wet_samples == 3  # clipped, not dropped
    with pytest.raises(EstimatorError):
        separation(np.array([]), dry)


def test_thresholds_split_the_gap_in_thirds_and_leave_room_for_hysteresis():
    rng = np.random.default_rng(0)
    wet, dry = rng.uniform(0.3, 0.4, 500), rng.uniform(0.02, 0.05, 500)
    th = propose(wet, dry, min_dwell_s=7.0)
    high, low = np.percentile(wet, 5), np.percentile(dry, 95)
    assert math.log(th.dry_below / low) == pytest.approx(math.log(high / low) / 3)
    assert math.log(th.wet_above / low) == pytest.approx(2 * math.log(high / low) / 3)
    assert (th.hysteresis, th.min_dwell_s, th.on_tau) == (HYSTERESIS, 7.0, False)
    close = propose(np.full(50, 1.0), np.full(50, 0.99))  # no gap: around the medians, bands still apart
    assert close.dry_below * (1 + HYSTERESIS) < close.wet_above * (1 - HYSTERESIS)
    assert close.dry_below < math.sqrt(0.99) < close.wet_above


def test_tau_thresholds_stay_measurable_below_the_longest_lag():
    wet_tau, dry_tau = np.full(40, 0.1), np.full(40, 1.0)  # seconds; 1.0 s = K·Δt, where τc is capped
    th = propose(1 / wet_tau, 1 / dry_tau, on_tau=True, most=1.0)
    assert th.on_tau and 1 / th.dry_below * (1 - HYSTERESIS) <= 1.0 / 1.001 + 1e-12  # reached at the cap


def test_replay_finds_the_dry_call_and_counts_moves_back_as_false():
    times = np.arange(0.0, 100.0, 0.5)
    falling = np.interp(times, [0, 30, 60, 100], [1.0, 1.0, 0.1, 0.1])
    th = Thresholds(0.6, 0.3, 0.05, 2.0)
    result = replay(times, falling, th, wet_until_s=30.0, dry_from_s=60.0)
    assert [s[1:] for s in result.states] == [("warming_up", "wet"), ("wet", "drying"), ("drying", "dry")]
    dry_at = result.states[-1][0]
    assert result.delay_s == pytest.approx(dry_at - 60.0) and result.delay_s < 0  # 0.3·0.95 is reached before 60 s
    assert result.false_transitions == 0 and result.flat_s == pytest.approx(30.0 + 99.5 - dry_at)
    bumpy = falling.copy()
    bumpy[(times > 80) & (times < 90)] = 0.9  # back to wet after the dry call
    worse = replay(times, bumpy, th, 30.0, 60.0)
    assert [s[1:] for s in worse.states[3:]] == [("dry", "wet"), ("wet", "dry")]
    assert worse.false_transitions == 1 and worse.false_per_hour == pytest.approx(3600 / worse.flat_s)
    held = falling.copy()
    held[times > 45] = np.nan  # the daemon holds the state: never called dry
    assert replay(times, held, th, 30.0, 60.0).delay_s is None


def test_a_drying_band_crossed_within_the_dwell_is_a_skipped_state():
    times = np.arange(0.0, 100.0, 0.5)
    th = Thresholds(0.6, 0.3, 0.05, 5.0)
    slow = np.interp(times, [0, 30, 60, 100], [1.0, 1.0, 0.1, 0.1])  # the band 0.57 -> 0.285 in ~13 s
    assert replay(times, slow, th, 30.0, 60.0).skipped == ()
    fast = np.interp(times, [0, 40, 44, 100], [1.0, 1.0, 0.1, 0.1])  # the band crossed in ~1.8 s < 5 s
    result = replay(times, fast, th, 30.0, 60.0)
    assert [s[1:] for s in result.states] == [("warming_up", "wet"), ("wet", "dry")]
    assert result.skipped == ("drying",) and result.delay_s is not None and result.false_transitions == 0
    # starting below the wet threshold: wet is skipped
    late = replay(times, np.interp(times, [0, 30, 60, 100], [0.5, 0.5, 0.1, 0.1]), th, 30.0, 60.0)
    assert late.states[0][1:] == ("warming_up", "drying") and late.skipped == ("wet",)
    # never dry: nothing is called skipped (the outcome is not sound anyway: never called dry)
    assert replay(times, np.full(times.shape, 0.9), th, 30.0, 60.0).skipped == ()


def _outcome(label: str, delay: float | None, cost: float, auc: float = 1.0, false: int = 0,
             d_prime: float = 20.0, lag: int = 5, skipped: tuple[str, ...] = ()) -> Outcome:
    th = Thresholds(0.6, 0.3)
    region = RegionOutcome(Separation(auc, d_prime, 10, 10), th, Replay([], delay, false, 3600.0, skipped))
    return Outcome(Candidate(label, True, Setting(100, lag)), {"r": region}, cost)


def test_a_candidate_that_skips_a_state_is_not_proposed_and_the_reason_says_so():
    skipping = _outcome("s1", 0.1, 1e-3, skipped=("drying",))  # the most timely and the cheapest
    showing = _outcome("s2", 2.0, 2e-3)
    assert recommend([skipping, showing])[0] is skipping  # what candidates alone would pick
    chosen, reason = choose([skipping, showing])
    assert chosen is showing and reason.endswith("1 candidate that would skip drying on this run is not proposed")
    assert skipped_states(skipping) == ("drying",) and skipped_states(showing) == ()
    none, why = choose([skipping])
    assert none is None and why.startswith("no candidate shows wet, drying and dry in turn") and "skip drying" in why


def test_the_choice_is_the_most_timely_sound_candidate_unless_a_cheaper_one_is_as_timely():
    timely = _outcome("s2", 2.0, 2e-3)
    nearly = _outcome("s1", -2.1, 1e-3)  # as timely within 10 %, half the cost
    late = _outcome("s3", 30.0, 0.5e-3)
    unsound = _outcome("tau_c", 0.0, 0.1e-3, false=1)
    front = pareto([timely, nearly, late, unsound])
    assert front == [timely, nearly, late]  # none beats another on both; the unsound one is out
    chosen, reason = recommend([timely, nearly, late, unsound])
    assert chosen is nearly and "2.1 s before the dry mark" in reason and "1 ms per frame" in reason
    none, why = recommend([unsound, _outcome("s1", None, 1e-3)])
    assert none is None and why.startswith("no candidate separates wet from dry")


def test_at_equal_timing_and_cost_the_better_separated_candidate_is_recommended():
    # both separate (AUC >= 0.95), both dry at the mark, same cost: d′ decides, whichever comes first
    for low, high in ((2.5, 4.0), (6.0, 40.0)):  # neither robust (d′ < 5); both
        touching = _outcome("contrast", 0.5, 1e-3, auc=0.96, d_prime=low)
        apart = _outcome("s3", 0.5, 1e-3, auc=0.99, d_prime=high, lag=10)
        for order in ([touching, apart], [apart, touching]):
            assert pareto(order) == [apart]  # the other is beaten on robustness alone
            chosen, reason = recommend(order)
            assert chosen is apart and f"d′ {high:.1f}" in reason
            assert ("no candidate reaches d′ 5 on every region" in reason) == (high < 5)
    # a robust candidate is preferred to a more timely one whose wet and dry samples touch
    touching = _outcome("contrast", 0.5, 1e-3, auc=0.96, d_prime=2.5)
    robust = _outcome("s3", 4.0, 2e-3, d_prime=25.0, lag=10)
    chosen, reason = recommend([touching, robust])
    assert chosen is robust and pareto([touching, robust]) == [robust]
    assert "contrast above noise, N=100 m=5 sliding calls it 0.5 s after the dry mark but with d′ 2.5 < 5" in reason
    # among the timely robust ones the cheaper is chosen, d′ beyond the bar does not buy cost
    cheaper = _outcome("s2", 4.0, 1e-3, d_prime=12.0)
    assert recommend([robust, cheaper])[0] is cheaper
    # none robust: among the timely ones the better separated, though it costs more
    fast = _outcome("s1", 0.5, 1e-3, d_prime=3.0)
    near = _outcome("s2", 0.52, 2e-3, d_prime=4.5)
    chosen, reason = recommend([fast, near])
    assert chosen is near and "but separates less (d′ 3.0)" in reason


def test_the_candidates_are_the_activities_the_daemon_judges_above_the_noise_where_it_has_a_floor():
    sliding, exponential = Setting(100, 5), Setting(100, 5, "exponential")
    labels = [c.label() for c in candidates([sliding])]
    assert [label.split(",")[0] for label in labels] == [
        "S1 above noise", "S1", "S2 above noise", "S2", "S3 above noise", "S3", "τc", "contrast above noise",
        "contrast", "Fujii above noise", "Fujii", "IM above noise", "IM"]
    assert len(candidates([exponential])) == 12  # no τc without a window
    other_lag = candidates([sliding, Setting(100, 10)])  # the contrast does not depend on m: scored once
    assert [c.setting.lag for c in other_lag if c.estimator == "contrast"] == [5, 5] and len(other_lag) == 24
    assert not any(c.estimator == "gd" for c in candidates([sliding]))  # GD only when asked for: its O(N) push
    with_gd = candidates([sliding, exponential], ("s2", "gd"))  # and only where the mode keeps a window
    assert [c.label() for c in with_gd if c.estimator == "gd"] == [
        "GD above noise, N=100 m=5 sliding", "GD, N=100 m=5 sliding"] and len(with_gd) == 6
    only = candidates([sliding, exponential], ("fujii", "contrast"))
    assert [(c.estimator, c.noise_floor, c.setting.mode, c.variant) for c in only] == [
        ("contrast", True, "sliding", "contrast@noise"), ("contrast", False, "sliding", "contrast"),
        ("fujii", True, "sliding", "fujii@noise"), ("fujii", False, "sliding", "fujii"),
        ("contrast", True, "exponential", "contrast@noise"), ("contrast", False, "exponential", "contrast"),
        ("fujii", True, "exponential", "fujii@noise"), ("fujii", False, "exponential", "fujii")]
