"""Time histories: per-region activity (S1, S2, S3, τc, and the field's streaming descriptors when
asked for) and a map histogram against time.

The paper (§3) reads drying from activity against time and from how the histogram of a map
moves. :func:`timeline` streams frames through a sliding window (:class:`SlidingWindow`, the
daemon's engine) and, every ``every`` frames once the window is full, records for each region
the mean of S1, S2 and S3 and the region's τc (from region-averaged correlations), plus the
histogram of one estimator's map over the whole frame. ``descriptors`` adds the region means of
the temporal contrast, Fujii, the inertia moment and the generalized differences
(docs/descriptors.md) as columns after the others (the engine keeps their sums only then; Fujii
is 200·S2 at q = 0, the timeline's q; GD's exact sum costs O(N) per pixel per frame).
Pure: frames in, arrays out.

When the samples fall on disjoint sets of N frames (``every`` a multiple of N, the paper's
Figs. 10–11 processing: sets of 200 frames), the engine runs in tumbling mode: the same maps at
the same frames, from exact sums of each completed set, without the ring of N frames a sliding
window keeps (the memory of a set follows the lag m, not N). The regions' τc then come from
:class:`~edgedsm.estimators.tau_regions.TumblingRegionTau`, which pools the lag products over
each region as the frames arrive instead of keeping them per pixel (the engine then keeps no τc
sums: about 41 bytes per pixel instead of 250 at K = 20 and 8 bits), with the engine's values to rounding.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from edgedsm.analysis import RegionBox
from edgedsm.errors import EstimatorError
from edgedsm.estimators import ESTIMATORS, SlidingWindow, noise, signal_quality
from edgedsm.estimators.correlation_time import ABOVE, BELOW, MEASURED, NO_SIGNAL, TauC
from edgedsm.estimators.noise import NoiseModel
from edgedsm.estimators.noise_summary import above_of, region_floor
from edgedsm.estimators.tau_regions import TumblingRegionTau, int64_problem
from edgedsm.noise_patches import NoisePatches, PatchWindow

STATUS_NAMES = {MEASURED: "measured", ABOVE: "above", BELOW: "below", NO_SIGNAL: "no_signal"}
COLUMNS = ("frame", "time_s", "region", "s1", "s2", "s3", "tau_c_frames", "tau_c_s", "tau_c_status",
           "mean_intensity", "signal", "s1_above_noise", "s2_above_noise", "s3_above_noise")
#: the columns of the light and the activity above the camera's noise (docs/noise.md)
NOISE_COLUMNS = COLUMNS[9:]
#: the field's descriptors the engine streams, which ``descriptors`` may add as columns (the bands:
#: split at ``band_split``, Hz of the timeline's ``dt``)
DESCRIPTORS = ("contrast", "fujii", "im", "gd", "band_low", "band_high", "band_ratio")


PATCH_SIDE = 64  # the daemon's default estimator.noise_patch
_NO_NOISE = (float("nan"), "off", float("nan"), float("nan"), float("nan"))


class _Light:
    """A region's light and its activity above the noise at one sample (the daemon's rules,
    docs/noise.md §5c, without its warnings): the model given, else the last the frames gave."""

    def __init__(self, model: NoiseModel | None) -> None:
        self.model = model
        self.given = model is not None

    def judge(self, patch: PatchWindow, estimates: dict[str, float], lag: int, verdict_of: str) -> tuple:
        if not self.given:
            with contextlib.suppress(EstimatorError):  # activity faster than a few frames, or dark: keep the last
                self.model = noise.from_frames(patch.frames, saturation=patch.top, mask=patch.mask)
        above = {}
        if self.model is not None:
            for name in ESTIMATORS:
                floor = region_floor(patch.frames, name, lag, self.model, mask=patch.mask, top=patch.top)
                above[name] = above_of(floor, estimates)
        light = signal_quality.light_stats(patch.frames, self.model or noise.from_datasheet(0.0, 0.0), patch.top,
                                           patch.mask)
        quality = signal_quality.signal_quality(light, above.get(verdict_of))
        return (light.mean, quality.verdict, *(float(above[n].value) if n in above else float("nan")
                                               for n in ESTIMATORS))


@dataclass
class Timeline:
    """Rows (one per region and sample) and the histogram of one map against time."""

    dt: float  # frame interval in seconds
    max_lag: int = 20  # K: τc above K frames is reported as K with status "above"
    rows: list[tuple] = field(default_factory=list)  # COLUMNS
    histogram_estimator: str = "s2"
    histogram_edges: np.ndarray = field(default_factory=lambda: np.zeros(0))
    histograms: list[np.ndarray] = field(default_factory=list)  # density per sample
    sample_frames: list[int] = field(default_factory=list)
    sample_times: list[float] = field(default_factory=list)  # seconds, one per sample
    descriptors: tuple[str, ...] = ()  # the descriptors' columns after COLUMNS

    @property
    def columns(self) -> tuple[str, ...]:
        """The rows' columns: COLUMNS, then one per descriptor."""
        return COLUMNS + self.descriptors

    def series(self, region: str, column: str) -> np.ndarray:
        """One column of one region against the samples, as float64."""
        index = self.columns.index(column)
        return np.array([row[index] for row in self.rows if row[2] == region], np.float64)

    def histogram_image(self) -> np.ndarray:
        """(bins, samples) densities, time along the columns."""
        return np.stack(self.histograms, axis=1) if self.histograms else np.zeros((0, 0))


def timeline(frames: Iterable[np.ndarray], regions: Mapping[str, np.ndarray], window: int, lag: int,
             every: int, dt: float = 1.0, max_lag: int = 20, bins: int = 64, histogram_estimator: str = "s2",
             histogram_range: tuple[float, float] | None = None, bits: int | None = None,
             times_s: Sequence[float] | None = None, mode: str | None = None, with_tau: bool = True,
             with_noise: bool = True, noise_model: NoiseModel | None = None,
             descriptors: Sequence[str] = (), band_split: float | None = None) -> Timeline:
    """Stream ``frames`` and sample the activity of each boolean (H, W) region every ``every`` frames.

    The first sample is at the frame that fills the window (index window-1), time = frame · dt,
    or ``times_s[frame]`` when given (a recording's own timestamps, in seconds: frames lost
    upstream then do not shift the time axis; τc in seconds still uses ``dt``).
    ``histogram_range`` defaults to 0 … 1.25 x the first sample's 99.5th percentile (activity
    maps are >= 0; one range for all samples so the picture compares like with like).
    ``mode``: the engine's window mode; None picks tumbling when ``every`` is a multiple of
    ``window`` (see the module docstring), else sliding. Without ``with_tau`` the engine keeps
    no τc sums (they are most of its memory: lag products and the window's edge frames for every
    pixel) and the τc columns read NaN with status "off".
    With ``with_noise`` each region's light and its S1, S2, S3 above the camera's noise floor
    (docs/noise.md) are judged on a patch at its centre, as the daemon judges them
    (:mod:`edgedsm.noise_patches`): ``noise_model`` (a datasheet's), else the last model the
    frames gave; the above-noise columns read NaN while there is none, the signal column
    "off" without ``with_noise``. ``descriptors``: some of :data:`DESCRIPTORS`, whose region
    means follow as columns (the histogram may be of one of them); ``band_split``: the bands'
    split in Hz (of ``dt``), default half the Nyquist frequency.
    """
    if every < 1:
        raise EstimatorError(f"the sampling step must be >= 1 frame, got {every}")
    if not regions:
        raise EstimatorError("no region to follow")
    if unknown := [name for name in descriptors if name not in DESCRIPTORS]:
        raise EstimatorError(f"the timeline streams the descriptors {', '.join(DESCRIPTORS)}, not {unknown}")
    extra = tuple(name for name in DESCRIPTORS if name in descriptors)
    if histogram_estimator not in ("s1", "s2", "s3", *extra):
        raise EstimatorError(f"histogram estimator must be one of {', '.join(('s1', 's2', 's3', *extra))}, "
                             f"got {histogram_estimator!r}")
    result = Timeline(dt=dt, max_lag=max_lag, histogram_estimator=histogram_estimator, descriptors=extra)
    if mode is None:
        mode = "tumbling" if every % window == 0 else "sliding"
    engine: SlidingWindow | None = None
    pooled: TumblingRegionTau | None = None  # tumbling: the regions' τc without per-pixel lag products
    patches: NoisePatches | None = None
    light = _Light(noise_model)
    count = 0
    for index, frame in enumerate(frames):
        if engine is None:
            for name, mask in regions.items():
                if mask.shape != frame.shape:
                    raise EstimatorError(f"region {name!r} is {mask.shape[1]}x{mask.shape[0]}, "
                                         f"the frames {frame.shape[1]}x{frame.shape[0]}")
            depth = bits or 8 * frame.dtype.itemsize
            in_engine = with_tau and (mode != "tumbling" or int64_problem(frame.shape, window, depth) is not None)
            estimators = ("s1", "s2", "s3", *extra, *(("tau_c",) if in_engine else ()))
            engine = SlidingWindow(frame.shape, window, lag, bits=bits, mode=mode, estimators=estimators,
                                   max_lag=max_lag if in_engine else None, dt=dt, band_split=band_split)
            if with_tau and not in_engine:
                pooled = TumblingRegionTau(frame.shape, regions, window, max_lag, depth)
            if with_noise:
                patches = NoisePatches({name: RegionBox.of(mask) for name, mask in regions.items()}, window,
                                       PATCH_SIDE, frame.dtype, bits)
        engine.push(frame)
        if patches is not None:
            patches.push(frame)
        if pooled is not None:
            pooled.push(frame)
        count = index + 1
        if not engine.ready or (index - (window - 1)) % every:
            continue
        maps = engine.maps(("s1", "s2", "s3", *extra))  # τc per region below: not the per-pixel τc map
        time = index * dt if times_s is None else float(times_s[index])
        windows = patches.take() if patches is not None else {}
        for name, mask in regions.items():
            means = (float(maps["s1"][mask].mean()), float(maps["s2"][mask].mean()), float(maps["s3"][mask].mean()))
            if with_tau:
                tau: TauC = pooled.last[name] if pooled is not None and pooled.last else engine.region_tau_c(mask)
                taus = (float(tau.tau), float(tau.tau) * dt, STATUS_NAMES[int(tau.status)])
            else:
                taus = (float("nan"), float("nan"), "off")
            judged = light.judge(windows[name], dict(zip(ESTIMATORS, means, strict=True)), lag,
                                 histogram_estimator) if name in windows else _NO_NOISE
            result.rows.append((index, time, name, *means, *taus, *judged,
                                *(float(maps[key][mask].mean()) for key in extra)))
        values = maps[histogram_estimator]
        if histogram_range is None:
            top = 1.25 * float(np.percentile(values, 99.5))
            histogram_range = (0.0, top if top > 0 else 1.0)
        density, edges = np.histogram(values, bins=bins, range=histogram_range, density=True)
        result.histograms.append(density)
        result.histogram_edges = edges
        result.sample_frames.append(index)
        result.sample_times.append(time)
        del maps, values  # the next sample's maps are not allocated beside these
    if not result.rows:
        raise EstimatorError(f"{count} frames do not fill one window of N = {window}")
    return result
