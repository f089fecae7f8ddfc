"""One streaming pass of a reference run at one window N, lag m and mode: every region's activity
over time, plain and as the daemon judges it above the camera's noise (docs/commissioning.md).

Frames are pushed one by one into the streaming engine (memory: the engine's window, as
``analyze --timeline``); every ``step`` frames once the window is full each region gives S1,
S2, S3 (its map means), τc in seconds (its pooled fit, sliding and tumbling windows) and, through
the daemon's own :class:`~edgedsm.daemon.signal_judge.SignalJudge` on the same noise patches,
S1, S2 and S3 above the noise floor, NaN while the daemon would hold the state (dark, saturated,
not speckle). The judge is the daemon's so that the delays a candidate is credited with are the
ones the daemon, configured from the snippet, shows.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from edgedsm.analysis import RegionBox, bounding_box
from edgedsm.config import DaemonConfig
from edgedsm.daemon.signal_judge import ModelKeeper, SignalJudge
from edgedsm.estimators import SlidingWindow
from edgedsm.noise_patches import NoisePatches

PLAIN = ("s1", "s2", "s3")
#: the series a pass gives per region: plain estimators, above the noise ("@noise"), τc in seconds
VARIANTS = (*PLAIN, "s1@noise", "s2@noise", "s3@noise", "tau_c")


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


def run_pass(frames: Iterable[np.ndarray], setting: Setting, config: DaemonConfig,
             masks: dict[str, np.ndarray], dt: float, step: int, bits: int | None = None,
             times_s: Sequence[float] | None = None, max_lag: int | None = None,
             on_frame: Callable[[], None] | None = None) -> Series:
    """Push ``frames`` through an engine at ``setting`` (cropped to the regions' bounding box, as
    the daemon's ``area = "regions"``: the activity does not depend on what lies outside), and
    sample every region every ``step`` frames (module docstring). ``max_lag``: τc's K (default
    the config's rule for this N and m)."""
    started = time.perf_counter()
    rows, cols = bounding_box(list(masks.values()))
    shape = (rows.stop - rows.start, cols.stop - cols.start)
    boxes = {name: RegionBox.of(mask).shifted(rows, cols) for name, mask in masks.items()}
    cropped = {name: np.ascontiguousarray(mask[rows, cols]) for name, mask in masks.items()}
    estimator = config.estimator.model_copy(update={"window": setting.window, "lag": setting.lag,
                                                    "mode": setting.mode, "max_lag": max_lag})
    lags = estimator.lags if setting.has_tau else None
    keeper = ModelKeeper(config.camera.noise.model() if config.camera.noise is not None else None)
    judges = {name: SignalJudge(config.model_copy(update={"estimator": estimator.model_copy(
        update={"activity": name, "noise_floor": True})}), keeper) for name in PLAIN}
    series = Series(setting, values={name: {variant: [] for variant in VARIANTS} for name in masks}, max_lag=lags)
    engine: SlidingWindow | None = None
    patches: NoisePatches | None = None
    wanted = (*PLAIN, "tau_c") if setting.has_tau else PLAIN
    for index, frame in enumerate(frames):
        pixels = np.ascontiguousarray(frame[rows, cols])
        if engine is None:
            engine = SlidingWindow(shape, setting.window, setting.lag, q=config.estimator.q, bits=bits,
                                   mode=setting.mode, estimators=wanted, max_lag=lags)
            patches = NoisePatches(boxes, setting.window, config.estimator.noise_patch, pixels.dtype, bits)
        engine.push(pixels)
        assert patches is not None
        patches.push(pixels)
        if on_frame is not None:
            on_frame()
        if not engine.ready or (index - (setting.window - 1)) % step:
            continue
        series.times.append(index * dt if times_s is None else float(times_s[index]))
        _sample(series, engine, patches, judges, cropped, dt, setting.has_tau)
    series.seconds = time.perf_counter() - started
    return series


def _sample(series: Series, engine: SlidingWindow, patches: NoisePatches, judges: dict[str, SignalJudge],
            masks: dict[str, np.ndarray], dt: float, with_tau: bool) -> None:
    maps = engine.maps(PLAIN)
    estimates = {name: {key: float(maps[key][mask].mean()) for key in PLAIN} for name, mask in masks.items()}
    windows = patches.take() if patches.full else {}
    if windows:
        for judge in judges.values():
            judge.assess(windows, estimates)
    for name, mask in masks.items():
        out = series.values[name]
        for key in PLAIN:
            out[key].append(estimates[name][key])
            judged = judges[key].judged(name, estimates[name][key], estimates[name]) if windows else None
            out[f"{key}@noise"].append(np.nan if judged is None else judged)
        if with_tau:
            tau = engine.region_tau_c(mask)
            held = judges["s3"].signals.get(name)
            out["tau_c"].append(np.nan if held is not None and held.signal in ("dark", "saturated", "not_speckle")
                                else float(tau.tau) * dt)
        else:
            out["tau_c"].append(np.nan)


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
