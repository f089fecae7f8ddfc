"""The candidates ``edgedsm tune`` weighs, what each does on the reference run, and the choice
(docs/commissioning.md).

A candidate is an estimator as the daemon judges it (``estimator.activity``: S1, S2, S3, Fujii,
IM, the temporal contrast or GD, plain or above the noise floor; or τc in seconds) at one window
N, lag m and mode; or the kinetics (τ in seconds over decades, docs/kinetics.md), which depends on
no window setting: one candidate per run, scored as τc is (its rate, thresholds in seconds). GD is
one only when asked for by name (series.DEFAULT_CANDIDATES: its push is
O(N) per pixel) and where the mode keeps a window. Its outcome on every region: the separation
of wet from dry, the proposed thresholds and what the state machine does with them
(:mod:`edgedsm.tuning.scoring`), and its cost per frame, measured by the engine at the camera's
frame size. The choice: among the candidates that separate every region (AUC >= GOOD_AUC), call
every region dry and make no false transition (*sound*), those whose d′ reaches ROBUST_D_PRIME on
every region (*robust*: their wet and dry samples are apart, and the thresholds between them far
from both) if any; among them, the Pareto front of (timing error, robustness, cost), the timing
error being the worst region's distance of its dry call from the dry mark (the mark is the
user's best knowledge of when the surface is dry: a call long before it is as suspect as one long
after; a τc that saturates at its longest lag calls dry early, for one) and the robustness the
worst region's d′. The recommended one is, among those within DELAY_SLACK of the most timely
one's error, the cheapest, then the best separated (when none is robust: the best separated, then
the cheapest). A more timely candidate that is sound but not robust is passed over, and the
reason says so: an AUC of 0.96 can hide wet and dry samples that touch, and thresholds between
them that the next run crosses.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from edgedsm.drying import Thresholds
from edgedsm.estimators import registry
from edgedsm.tuning.scoring import Replay, Separation, propose, replay, separation
from edgedsm.tuning.series import DEFAULT_CANDIDATES, JUDGEABLE, KINETICS, WITH_FLOOR, Series, Setting, in_mode

#: the activities judged in seconds, small when wet (scored as their rate 1/τ)
IN_SECONDS = ("tau_c", KINETICS)

GOOD_AUC = 0.95  # below: wet and dry overlap too much to trust thresholds
USABLE_AUC = 0.9  # below, for every candidate: the run cannot be tuned (exit 65)
DELAY_SLACK = 0.1  # a cheaper or more robust candidate within this share of the fastest's delay is preferred
#: d′ (log activity, pooled σ: scoring.separation) from which a candidate is robust. With the
#: thresholds at the thirds of the gap between the wet samples' 5th percentile and the dry ones'
#: 95th (scoring.propose), each lies 1.645 + (d′ - 3.29)/3 = 0.548 + d′/3 σ from the nearer
#: distribution's mean (two normal distributions of one σ): below d′ = 3.29 the percentiles cross
#: (the samples touch); at 5, 2.2 σ, a single sample beyond it with probability 1.4 %, which the
#: dwell, several samples in a row, absorbs
ROBUST_D_PRIME = 5.0
#: activities of the fused pass that do not depend on the lag m (the contrast: σ/⟨I⟩ of the window;
#: the registry's): scored at one lag per window and mode, the first tried
LAG_FREE = tuple(r.name for r in registry.records(activity=True, source="fused") if not r.uses_lag)
#: each activity's short label (the registry's)
NAMES = {r.name: r.label for r in registry.records(activity=True)}


@dataclass(frozen=True)
class Candidate:
    estimator: str  # an estimator.activity (edgedsm.estimators.registry.activities())
    noise_floor: bool  # judged above the noise floor (those of series.WITH_FLOOR)
    setting: Setting

    @property
    def variant(self) -> str:
        """The series of :mod:`edgedsm.tuning.series` this candidate is judged on."""
        if self.estimator in IN_SECONDS:
            return self.estimator
        return f"{self.estimator}@noise" if self.noise_floor else self.estimator

    def label(self) -> str:
        if self.estimator == KINETICS:  # no window setting: its reference frames at geometric ages
            return registry.get(KINETICS).label
        what = registry.get(self.estimator).label + (" above noise" if self.noise_floor and self.estimator != "tau_c"
                                                      else "")
        return f"{what}, {self.setting.label()}"


@dataclass(frozen=True)
class RegionOutcome:
    separation: Separation
    thresholds: Thresholds
    replay: Replay


@dataclass(frozen=True)
class Outcome:
    candidate: Candidate
    regions: dict[str, RegionOutcome]
    cost_s: float  # engine push per frame at the camera's size, seconds

    @property
    def auc(self) -> float:
        return min(r.separation.auc for r in self.regions.values())

    @property
    def d_prime(self) -> float:
        return min(r.separation.d_prime for r in self.regions.values())

    @property
    def delay_s(self) -> float:
        """The worst region's delay (inf: a region never called dry)."""
        delays = [r.replay.delay_s for r in self.regions.values()]
        return math.inf if any(d is None for d in delays) else max(d for d in delays if d is not None)

    @property
    def timing_error_s(self) -> float:
        """The worst region's |dry call - dry mark| (inf: a region never called dry)."""
        delays = [r.replay.delay_s for r in self.regions.values()]
        return math.inf if any(d is None for d in delays) else max(abs(d) for d in delays if d is not None)

    @property
    def false_per_hour(self) -> float:
        return sum(r.replay.false_per_hour for r in self.regions.values())

    @property
    def robust(self) -> bool:
        return self.d_prime >= ROBUST_D_PRIME

    @property
    def sound(self) -> bool:
        """Separates every region, calls every one dry, and no false transition."""
        return self.auc >= GOOD_AUC and math.isfinite(self.delay_s) and self.false_per_hour == 0


def candidates(settings: Iterable[Setting], estimators: Sequence[str] = DEFAULT_CANDIDATES) -> list[Candidate]:
    """Every variant of ``estimators`` (among series.JUDGEABLE) at each setting: above the noise
    and plain where the daemon has a floor, else plain; τc and GD only where the mode keeps a
    window; a LAG_FREE one at the first of the settings that differ only in the lag."""
    out = []
    for setting in settings:
        for estimator in (name for name in JUDGEABLE if name in in_mode(estimators, setting.mode)):
            if estimator in LAG_FREE and any(c.estimator == estimator and (c.setting.window, c.setting.mode) ==
                                             (setting.window, setting.mode) for c in out):
                continue
            if estimator in WITH_FLOOR:
                out += [Candidate(estimator, True, setting), Candidate(estimator, False, setting)]
            elif estimator != "tau_c" or setting.has_tau:
                out.append(Candidate(estimator, False, setting))
    return out


def evaluate(candidate: Candidate, series: Series, wet_until_s: float, dry_from_s: float,
             dwell_s: dict[str, float], dt: float, cost_s: float) -> Outcome | str:
    """The candidate's outcome on the pass ``series`` of its setting; where a region has no usable
    wet or dry sample (the daemon would hold its state throughout one part: dark, saturated, not
    speckle), why it cannot be scored."""
    times = np.asarray(series.times, np.float64)
    on_tau = candidate.estimator in IN_SECONDS
    regions = {}
    for name in series.values:
        observed = series.array(name, candidate.variant)
        activity = 1.0 / observed if on_tau else observed  # τc as its rate (scoring's convention)
        wet = activity[(times <= wet_until_s) & np.isfinite(activity)]
        dry = activity[(times >= dry_from_s) & np.isfinite(activity)]
        if wet.size == 0 or dry.size == 0:
            part = "wet" if wet.size == 0 else "dry"
            return (f"region {name}: no {part} sample (the daemon would hold the state: its light is dark, "
                    "saturated or not speckle)" if candidate.noise_floor or on_tau else
                    f"region {name}: no {part} sample")
        # the longest τ it can show: τc's K·Δt, the kinetics' oldest reference (a dry call needs it reached)
        longest = series.kinetics_oldest_s if candidate.estimator == KINETICS else (
            series.max_lag * dt if on_tau and series.max_lag else None)
        most = 1.0 / longest if longest else None
        thresholds = propose(wet, dry, on_tau=on_tau, min_dwell_s=dwell_s[name], most=most)
        regions[name] = RegionOutcome(separation(wet, dry), thresholds,
                                      replay(times, observed, thresholds, wet_until_s, dry_from_s))
    return Outcome(candidate, regions, cost_s)


def _beats(p: Outcome, o: Outcome) -> bool:
    """``p`` is at least as timely, robust and cheap as ``o``, and better on one of them."""
    at_least = p.timing_error_s <= o.timing_error_s and p.d_prime >= o.d_prime and p.cost_s <= o.cost_s
    return at_least and (p.timing_error_s < o.timing_error_s or p.d_prime > o.d_prime or p.cost_s < o.cost_s)


def pareto(outcomes: Sequence[Outcome]) -> list[Outcome]:
    """The robust sound outcomes (the sound ones when none is robust) that no other beats on
    timing error, robustness (d′) and cost together, most timely first."""
    sound = [o for o in outcomes if o.sound]
    pool = [o for o in sound if o.robust] or sound
    front = [o for o in pool if not any(_beats(p, o) for p in pool)]
    return sorted(front, key=lambda o: (o.timing_error_s, o.cost_s, -o.d_prime))


def recommend(outcomes: Sequence[Outcome]) -> tuple[Outcome | None, str]:
    """The recommended outcome and the reason, in one sentence (module docstring); None with the
    best separation found when no candidate is sound."""
    front = pareto(outcomes)
    if not front:
        best = max(outcomes, key=lambda o: (o.auc, -o.false_per_hour), default=None)
        if best is None:
            return None, "no candidate could be scored (no wet or no dry samples)"
        return None, (f"no candidate separates wet from dry on every region without a false transition: the best, "
                      f"{best.candidate.label()}, has AUC {best.auc:.3f}, {best.false_per_hour:.1f} false "
                      f"transitions per hour and calls dry {_delay(best.delay_s)}")
    fastest = front[0]
    timely = [o for o in front
              if o.timing_error_s <= fastest.timing_error_s + DELAY_SLACK * max(fastest.timing_error_s, 1.0)]
    chosen = min(timely, key=lambda o: (o.cost_s, -o.d_prime) if o.robust else (-o.d_prime, o.cost_s))
    reason = (f"{chosen.candidate.label()} calls every region dry {_delay(chosen.delay_s)} with "
              f"no false transition (AUC {chosen.auc:.3f}, d′ {_d_prime(chosen.d_prime)}) at "
              f"{chosen.cost_s * 1e3:.3g} ms per frame")
    if chosen is not fastest:
        reason += (f"; the most timely, {fastest.candidate.label()}, calls it {_delay(fastest.delay_s)} but costs "
                   f"{fastest.cost_s / chosen.cost_s:.1f}× as much" if chosen.cost_s < fastest.cost_s else
                   f"; the most timely, {fastest.candidate.label()}, calls it {_delay(fastest.delay_s)} but "
                   f"separates less (d′ {_d_prime(fastest.d_prime)})")
    if not chosen.robust:
        reason += (f"; no candidate reaches d′ {ROBUST_D_PRIME:g} on every region: its wet and dry samples nearly "
                   "touch and the thresholds between them are fragile, check them on a second run")
    else:
        passed = [o for o in outcomes if o.sound and not o.robust and o.timing_error_s < chosen.timing_error_s]
        if passed:
            nearest = min(passed, key=lambda o: o.timing_error_s)
            reason += (f"; {nearest.candidate.label()} calls it {_delay(nearest.delay_s)} but with d′ "
                       f"{_d_prime(nearest.d_prime)} < {ROBUST_D_PRIME:g} its thresholds lie close to the wet or the "
                       "dry samples")
    return chosen, reason


def _delay(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "never"
    return f"{seconds:.1f} s after the dry mark" if seconds >= 0 else f"{-seconds:.1f} s before the dry mark"


def _d_prime(value: float) -> str:
    return f"{value:.1f}" if value < 100 else "> 100"
