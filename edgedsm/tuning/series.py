"""One streaming pass of a reference run at one window N, lag m and mode: every region's activity
over time, plain and as the daemon judges it above the camera's noise (docs/commissioning.md).

The pass is the daemon's measurement: the measurement core (:class:`edgedsm.measurement.Core`)
with the config at this setting, its engine from the config's
:class:`~edgedsm.measurement.EngineSpec`, its region means from the engine's live sums, its signal
judge on the daemon's noise patches (``estimator.noise_patch``; judged at every sample, where the
daemon judges them every ``cadence.stats_interval_s`` and turns the means between by the last
floors: the floors here follow a short run as the daemon's follow a long one). Every ``step``
frames once the window is full each region gives the activities the daemon can judge on
(``estimator.activity``): S1, S2, S3 and the field's descriptors contrast, Fujii, IM and (asked
for by name) GD (docs/descriptors.md), τc in seconds (its pooled fit, sliding and tumbling
windows) and those with a floor above it, NaN while the daemon would hold the state (dark,
saturated, not speckle). The judge keeps every candidate's floor from the same patches and model
(one judge: what each would be judged on were it the activity), so that the delays a candidate is
credited with are the ones the daemon, configured from the snippet, shows.

The kinetics (``estimator.activity = "kinetics"``; docs/kinetics.md) depend on no window setting:
the pass given a ``[kinetics]`` section pushes every frame into the core's reference frames too, as
the daemon's pipeline does, and samples each region's judged seconds (τ, or its bound when above or
below; NaN where the daemon holds the state: dark, saturated, not speckle, warming up).

Fujii is 200·S2 at q = 0, and the daemon judged on it runs its engine at q = 0
(``estimator.engine_q``); when the config's q is not 0 (S2 is judged at that q), Fujii comes
from a companion engine at q = 0 in the same pass, fed the same frames.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from edgedsm.config import DaemonConfig
from edgedsm.config.estimator import EstimatorSection
from edgedsm.config.kinetics import KineticsSection
from edgedsm.estimators import registry
from edgedsm.estimators.region_box import bounding_box
from edgedsm.measurement import Core, EngineSpec, RegionReading
from edgedsm.measurement.judge import FLOORED
from edgedsm.measurement.kinetics import judged_seconds
from edgedsm.validation import validate

PLAIN = registry.paper_maps()  # S1, S2, S3: always formed (the daemon does; S3's and τc's floors need S1)
#: every window activity the daemon can judge on (``estimator.activity``), in the order candidates are
#: listed; not the bands' (the band ratio: its split would be one more tuned setting, and the
#: exponential mode has no bands), nor the region-level measures' (KINETICS: no window setting to
#: tune, scored once per run)
JUDGEABLE = tuple(name for name in registry.activities()
                  if registry.get(name).source != "bins" and not registry.get(name).region_level)
#: the kinetics (docs/kinetics.md): its own reference frames, scored in the first pass when the run allows it
KINETICS = "kinetics"
#: what ``tune --estimators`` may name
TUNABLE = (*JUDGEABLE, KINETICS)
#: those tried unless asked for by name: all but those whose push reads the window (cost O(N): GD),
#: which makes every pass of a setting several times longer (docs/commissioning.md), so that a budget
#: would cover fewer settings
DEFAULT_CANDIDATES = (*(name for name in JUDGEABLE if registry.get(name).cost != "O(N)"), KINETICS)
#: those the daemon judges above a noise floor (τc is held, not lowered)
WITH_FLOOR = tuple(name for name in JUDGEABLE if name in FLOORED)


@dataclass(frozen=True)
class Setting:
    """What one pass runs: window N, lag m (frames) and the engine's mode."""

    window: int
    lag: int
    mode: str = "sliding"

    @property
    def has_tau(self) -> bool:
        return self.mode != "exponential"

    def label(self) -> str:
        return f"N={self.window} m={self.lag} {self.mode}"


@dataclass
class Series:
    """A pass's result: sample times (s) and per region, per variant, the values (NaN: none)."""

    setting: Setting
    times: list[float] = field(default_factory=list)
    values: dict[str, dict[str, list[float]]] = field(default_factory=dict)
    max_lag: int | None = None  # τc's longest lag K (frames)
    seconds: float = 0.0  # wall time of the pass
    # with the kinetics: the oldest reference's age (s: the longest τ it can read) and a read's time (s)
    kinetics_oldest_s: float | None = None
    kinetics_read_s: float | None = None

    def array(self, region: str, variant: str) -> np.ndarray:
        return np.asarray(self.values[region][variant], np.float64)


def in_mode(estimators: Sequence[str], mode: str) -> tuple[str, ...]:
    """``estimators`` without those the engine cannot form in window ``mode`` (the registry's
    modes: GD and τc not in the exponential mode)."""
    return registry.in_mode(estimators, mode)


def variants(estimators: Sequence[str], has_tau: bool = True, kinetics: bool = False) -> tuple[str, ...]:
    """The series a pass of ``estimators`` (among JUDGEABLE) gives per region: each plain (S1-S3
    always), those with a floor also above it ("@noise"), τc in seconds where the mode has it, the
    kinetics' judged seconds with ``kinetics``."""
    plain = [*PLAIN, *(name for name in JUDGEABLE if name in estimators and name not in (*PLAIN, "tau_c"))]
    floored = [f"{name}@noise" for name in WITH_FLOOR if name in estimators]
    return (*plain, *floored, *(("tau_c",) if "tau_c" in estimators and has_tau else ()),
            *((KINETICS,) if kinetics else ()))


def run_pass(frames: Iterable[np.ndarray], setting: Setting, config: DaemonConfig,
             masks: dict[str, np.ndarray], dt: float, step: int, bits: int | None = None,
             times_s: Sequence[float] | None = None, max_lag: int | None = None,
             on_frame: Callable[[], None] | None = None, estimators: Sequence[str] = DEFAULT_CANDIDATES,
             kinetics: KineticsSection | None = None) -> Series:
    """Push ``frames`` through the measurement core at ``setting`` (cropped to the regions' bounding
    box, as the daemon's ``area = "regions"``: the activity does not depend on what lies outside),
    and sample every region every ``step`` frames (module docstring). ``max_lag``: τc's K (default
    the config's rule for this N and m). ``estimators``: the activities wanted (among JUDGEABLE;
    GD only where the mode keeps a window). ``kinetics``: the section to measure the kinetics with
    in this pass (None: not measured; the config's own ``[kinetics]`` is not pushed by every pass)."""
    started = time.perf_counter()
    estimators = in_mode(estimators, setting.mode)
    rows, cols = bounding_box(list(masks.values()))
    cropped = {name: np.ascontiguousarray(mask[rows, cols]) for name, mask in masks.items()}
    with_tau = setting.has_tau and "tau_c" in estimators
    # the judge's activity: S3 (its floor is τc's signal share) unless a floored candidate is wanted
    floored = tuple(name for name in WITH_FLOOR if name in estimators or (name == "s3" and with_tau))
    estimator = validate(EstimatorSection, {
        **config.estimator.model_dump(exclude_unset=True), "window": setting.window, "lag": setting.lag,
        "mode": setting.mode, "max_lag": max_lag, "activity": "s3", "noise_floor": True, "tau_c": with_tau},
        "estimator")
    settings = config.model_copy(update={"estimator": estimator, "kinetics": kinetics or KineticsSection()})
    q = config.estimator.q
    # a map formed at q = 0 (Fujii) needs an engine at q = 0 (its daemon runs so): the main one when
    # q is 0, else a companion
    at_zero = tuple(name for name in estimators if q != 0.0 and registry.get(name).needs_q_zero)
    extra = tuple(name for name in JUDGEABLE if name in estimators and name not in (*PLAIN, "tau_c", *at_zero))
    spec = EngineSpec.of_sections(estimator, tau_c=with_tau, extra=extra)
    companions = [spec.replaced(q=0.0, estimators=at_zero)] if at_zero else []
    core = Core(settings, cropped, patch=config.estimator.noise_patch, floored=floored, dt=dt, spec=spec,
                companions=companions)
    series = Series(setting, values={name: {variant: [] for variant in variants(estimators, setting.has_tau,
                                                                                kinetics is not None)}
                                     for name in masks}, max_lag=spec.max_lag)
    for index, frame in enumerate(frames):
        core.push(np.ascontiguousarray(frame[rows, cols]), bits)
        if on_frame is not None:
            on_frame()
        if not core.ready or (index - (setting.window - 1)) % step:
            continue
        now = index * dt if times_s is None else float(times_s[index])
        series.times.append(now)
        _sample(series, core, core.read(now).readings)
    if kinetics is not None and core.kinetics is not None:
        series.kinetics_oldest_s = kinetics.longest_age_s / 2.0 ** (1.0 / kinetics.per_octave)
        series.kinetics_read_s = _best_time(lambda: core.kinetics.read(dt))  # the references as the run left them
    series.seconds = time.perf_counter() - started
    return series


def _best_time(call: Callable[[], object], repeats: int = 3) -> float:
    best = float("inf")
    for _ in range(repeats):
        started = time.perf_counter()
        call()
        best = min(best, time.perf_counter() - started)
    return best


def _sample(series: Series, core: Core, readings: dict[str, RegionReading]) -> None:
    judge = core.judgement.judge
    for name, out in series.values.items():
        reading = readings[name]
        for variant, values in out.items():
            key, _, floored = variant.partition("@")
            if key == KINETICS:  # τ in s, or its bound; NaN where the daemon holds the state
                judged = judged_seconds(reading.kinetics)
                values.append(np.nan if judged is None else judged)
                continue
            if key == "tau_c":
                held = judge.held(name) or reading.tau_c_s is None
                values.append(np.nan if held else reading.tau_c_s)
                continue
            if not floored:
                values.append(reading.values[key])
                continue
            judged = judge.judged_as(name, key, reading.values[key], reading.values)
            values.append(np.nan if judged is None else judged)


def push_cost(frames: Sequence[np.ndarray], estimators: tuple[str, ...], setting: Setting, bits: int | None,
              max_lag: int | None = None, q: float = 1.0, repeats: int = 3) -> float:
    """Seconds per push of one engine computing only ``estimators`` at ``setting`` on frames of the
    camera's size, measured: the best of ``repeats`` timings over ``frames`` (pushed after a
    window's worth to fill it; the first, compiling, push is not timed)."""
    spec = EngineSpec(setting.window, setting.lag, q, setting.mode, tuple(estimators), max_lag)
    engine = spec.engine(frames[0].shape, bits)
    fill = [frames[k % len(frames)] for k in range(setting.window + 1)]
    for frame in fill:
        engine.push(frame)
    best = float("inf")
    for _ in range(repeats):
        started = time.perf_counter()
        for frame in frames:
            engine.push(frame)
        best = min(best, (time.perf_counter() - started) / len(frames))
    return best


def kinetics_cost(frames: Sequence[np.ndarray], section: KineticsSection, masks: dict[str, np.ndarray], dt: float,
                  repeats: int = 3) -> float:
    """Seconds per push of every region's kinetics (``masks`` in the frames' shape) into its
    reference frames, measured: the best of ``repeats`` timings over ``frames`` (after a first,
    compiling, round)."""
    from edgedsm.measurement.kinetics import KineticsRegions

    regions = KineticsRegions(section, masks)
    for frame in frames:
        regions.push(frame, dt)
    return _best_time(lambda: [regions.push(frame, dt) for frame in frames], repeats) / len(frames)
