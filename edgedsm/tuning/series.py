"""One streaming pass of a reference run at one window N, lag m and mode: every region's activity
over time, plain and as the daemon judges it above the camera's noise (docs/commissioning.md).

Frames are pushed one by one into the streaming engine (memory: the engine's window, as
``analyze --timeline``); every ``step`` frames once the window is full each region gives the
activities the daemon can judge on (``estimator.activity``): S1, S2, S3 and the field's
descriptors contrast, Fujii, IM and (asked for by name) GD (docs/descriptors.md), as the daemon's region means
(:func:`~edgedsm.estimators.region_stats.region_moments` on the engine's live sums, the
daemon's own reduction), τc in seconds (its pooled fit, sliding and tumbling windows) and,
through the daemon's own :class:`~edgedsm.daemon.signal_judge.SignalJudge` on the same noise
patches, S1, S2, S3, Fujii, IM, the contrast and GD above their noise floors, NaN while the
daemon would hold the state (dark, saturated, not speckle). The judge is the daemon's so that the
delays a candidate is credited with are the ones the daemon, configured from the snippet, shows.

Fujii is 200·S2 at q = 0, and the daemon judged on it runs its engine at q = 0
(``estimator.engine_q``); when the config's q is not 0 (S2 is judged at that q), Fujii comes
from a second engine at q = 0 in the same pass, fed the same frames.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from edgedsm.analysis import RegionBox, bounding_box
from edgedsm.config import DaemonConfig
from edgedsm.config.estimator import DESCRIPTOR_ACTIVITIES, PAPER_MAPS
from edgedsm.daemon.signal_judge import ModelKeeper, SignalJudge
from edgedsm.estimators import SlidingWindow
from edgedsm.estimators.noise_summary import ESTIMATORS as FLOORED
from edgedsm.estimators.region_stats import RegionLayout, RegionPlan, region_moments
from edgedsm.estimators.streaming import PARALLEL_MIN_PIXELS
from edgedsm.estimators.value_set import gd_mode_problem
from edgedsm.noise_patches import NoisePatches

PLAIN = PAPER_MAPS  # S1, S2, S3: always formed (the daemon does; S3's and τc's floors need S1)
#: every activity the daemon can judge on (``estimator.activity``), in the order candidates are listed;
#: not the band ratio yet (its split would be one more tuned setting, and the exponential mode has no bands)
JUDGEABLE = (*PAPER_MAPS, "tau_c", *(name for name in DESCRIPTOR_ACTIVITIES if name != "band_ratio"))
#: those tried unless asked for by name: all but GD, whose O(N)-per-pixel push makes every pass of
#: a setting several times longer (docs/commissioning.md), so that a budget would cover fewer settings
DEFAULT_CANDIDATES = tuple(name for name in JUDGEABLE if name != "gd")
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

    def array(self, region: str, variant: str) -> np.ndarray:
        return np.asarray(self.values[region][variant], np.float64)


def in_mode(estimators: Sequence[str], mode: str) -> tuple[str, ...]:
    """``estimators`` without those the engine cannot keep in window ``mode`` (GD in the exponential
    mode; τc is left to ``Setting.has_tau``)."""
    return tuple(name for name in estimators if not (name == "gd" and gd_mode_problem(mode)))


def variants(estimators: Sequence[str], has_tau: bool = True) -> tuple[str, ...]:
    """The series a pass of ``estimators`` (among JUDGEABLE) gives per region: each plain (S1-S3
    always), those with a floor also above it ("@noise"), τc in seconds where the mode has it."""
    plain = [*PLAIN, *(name for name in DESCRIPTOR_ACTIVITIES if name in estimators)]
    floored = [f"{name}@noise" for name in WITH_FLOOR if name in estimators]
    return (*plain, *floored, *(("tau_c",) if "tau_c" in estimators and has_tau else ()))


def run_pass(frames: Iterable[np.ndarray], setting: Setting, config: DaemonConfig,
             masks: dict[str, np.ndarray], dt: float, step: int, bits: int | None = None,
             times_s: Sequence[float] | None = None, max_lag: int | None = None,
             on_frame: Callable[[], None] | None = None, estimators: Sequence[str] = DEFAULT_CANDIDATES) -> Series:
    """Push ``frames`` through an engine at ``setting`` (cropped to the regions' bounding box, as
    the daemon's ``area = "regions"``: the activity does not depend on what lies outside), and
    sample every region every ``step`` frames (module docstring). ``max_lag``: τc's K (default
    the config's rule for this N and m). ``estimators``: the activities wanted (among JUDGEABLE;
    GD only where the mode keeps a window)."""
    started = time.perf_counter()
    estimators = in_mode(estimators, setting.mode)
    rows, cols = bounding_box(list(masks.values()))
    shape = (rows.stop - rows.start, cols.stop - cols.start)
    boxes = {name: RegionBox.of(mask).shifted(rows, cols) for name, mask in masks.items()}
    cropped = {name: np.ascontiguousarray(mask[rows, cols]) for name, mask in masks.items()}
    estimator = config.estimator.model_copy(update={"window": setting.window, "lag": setting.lag,
                                                    "mode": setting.mode, "max_lag": max_lag})
    with_tau = setting.has_tau and "tau_c" in estimators
    lags = estimator.lags if with_tau else None
    q = config.estimator.q
    # Fujii needs an engine at q = 0 (its daemon runs so): the main one when q is 0, else its own
    separate_fujii = "fujii" in estimators and q != 0.0
    maps = (*PLAIN, *(name for name in DESCRIPTOR_ACTIVITIES if name in estimators
                      and not (name == "fujii" and separate_fujii)))
    keeper = ModelKeeper(config.camera.noise.model() if config.camera.noise is not None else None)
    # the judges' activities; S3's also holds τc (a region judged on τc has its light judged with S3)
    judged = [name for name in WITH_FLOOR if name in estimators or (name == "s3" and with_tau)]
    judges = {name: SignalJudge(config.model_copy(update={"estimator": estimator.model_copy(
        update={"activity": name, "noise_floor": True, **({"q": 0.0} if name == "fujii" else {})})}), keeper)
        for name in judged}
    series = Series(setting, values={name: {variant: [] for variant in variants(estimators, setting.has_tau)}
                                     for name in masks}, max_lag=lags)
    layout = RegionLayout.of({name: RegionPlan.of(box, shape) for name, box in boxes.items()})
    engines: list[tuple[SlidingWindow, tuple[str, ...]]] = []
    patches: NoisePatches | None = None
    for index, frame in enumerate(frames):
        pixels = np.ascontiguousarray(frame[rows, cols])
        if not engines:
            engines.append((SlidingWindow(shape, setting.window, setting.lag, q=q, bits=bits, mode=setting.mode,
                                          estimators=(*maps, "tau_c") if with_tau else maps, max_lag=lags), maps))
            if separate_fujii:
                engines.append((SlidingWindow(shape, setting.window, setting.lag, q=0.0, bits=bits,
                                              mode=setting.mode, estimators=("fujii",)), ("fujii",)))
            patches = NoisePatches(boxes, setting.window, config.estimator.noise_patch, pixels.dtype, bits)
        for engine, _ in engines:
            engine.push(pixels)
        assert patches is not None
        patches.push(pixels)
        if on_frame is not None:
            on_frame()
        if not engines[0][0].ready or (index - (setting.window - 1)) % step:
            continue
        series.times.append(index * dt if times_s is None else float(times_s[index]))
        estimates = _estimates(engines, layout)
        _sample(series, engines[0][0], estimates, patches, judges, cropped, dt, with_tau)
    series.seconds = time.perf_counter() - started
    return series


def _estimates(engines: list[tuple[SlidingWindow, tuple[str, ...]]], layout: RegionLayout
               ) -> dict[str, dict[str, float]]:
    """Every region's mean of every map, as the daemon's pipeline reduces them
    (:meth:`edgedsm.daemon.measurement.Measurement.snapshot`: the live sums, means only)."""
    out: dict[str, dict[str, float]] = {}
    for engine, names in engines:
        moments = region_moments(engine.snapshot(names, live=True), layout, names, spread=False,
                                 parallel=engine.shape[0] * engine.shape[1] >= PARALLEL_MIN_PIXELS)
        for region, per_map in moments.items():
            out.setdefault(region, {}).update({key: m.mean for key, m in per_map.items()})
    return out


def _sample(series: Series, engine: SlidingWindow, estimates: dict[str, dict[str, float]], patches: NoisePatches,
            judges: dict[str, SignalJudge], masks: dict[str, np.ndarray], dt: float, with_tau: bool) -> None:
    windows = patches.take() if patches.full else {}
    if windows:
        for judge in judges.values():
            judge.assess(windows, estimates)
    for name, mask in masks.items():
        out = series.values[name]
        for variant, values in out.items():
            key, _, floored = variant.partition("@")
            if key == "tau_c":
                continue
            if not floored:
                values.append(estimates[name][key])
                continue
            judged = judges[key].judged(name, estimates[name][key], estimates[name]) if windows else None
            values.append(np.nan if judged is None else judged)
        if with_tau:
            tau = engine.region_tau_c(mask)
            held = judges["s3"].signals.get(name)
            out["tau_c"].append(np.nan if held is not None and held.signal in ("dark", "saturated", "not_speckle")
                                else float(tau.tau) * dt)


def push_cost(frames: Sequence[np.ndarray], estimators: tuple[str, ...], setting: Setting, bits: int | None,
              max_lag: int | None = None, q: float = 1.0, repeats: int = 3) -> float:
    """Seconds per push of one engine computing only ``estimators`` at ``setting`` on frames of the
    camera's size, measured: the best of ``repeats`` timings over ``frames`` (pushed after a
    window's worth to fill it; the first, compiling, push is not timed)."""
    shape = frames[0].shape
    engine = SlidingWindow(shape, setting.window, setting.lag, q=q, bits=bits, mode=setting.mode,
                           estimators=estimators, max_lag=max_lag)
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
