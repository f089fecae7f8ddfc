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

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from edgedsm.config import DaemonConfig
from edgedsm.config.estimator import EstimatorSection
from edgedsm.config.kinetics import KineticsSection
from edgedsm.errors import EstimatorError
from edgedsm.estimators import SlidingWindow, registry
from edgedsm.estimators.correlation_time import TauC
from edgedsm.estimators.noise import NoiseModel
from edgedsm.estimators.snapshot import maps_from
from edgedsm.estimators.tau_regions import TumblingRegionTau, int64_problem
from edgedsm.measurement import Core, EngineSpec, RegionReading
from edgedsm.measurement import kinetics as region_kinetics
from edgedsm.measurement import stages as region_stages
from edgedsm.measurement.tau import STATUS_NAMES
from edgedsm.noise_patches import MAX_PATCH_FRAMES
from edgedsm.validation import validate

PAPER = registry.paper_maps()  # S1, S2, S3: always columns
COLUMNS = ("frame", "time_s", "region", *PAPER, "tau_c_frames", "tau_c_s", "tau_c_status",
           "mean_intensity", "signal", *(f"{name}_above_noise" for name in PAPER),
           "estimator", "activity", "noise_floor", "noise_view")
#: the columns of the light and the activity above the camera's noise (docs/noise.md)
NOISE_COLUMNS = COLUMNS[9:]
#: the field's descriptors the engine streams, which ``descriptors`` may add as columns (the bands:
#: split at ``band_split``, Hz of the timeline's ``dt``)
DESCRIPTORS = tuple(name for name in registry.names() if name not in (*PAPER, "tau_c")
                    and registry.get(name).modes)
NAN = float("nan")
#: pixel-frames of the regions' noise windows up to which a timeline judges every pixel of them
#: (2^27: the 100 frames of a 1092x614 video, 128 MiB at 8 bits), beyond which the daemon's patch
REGION_VIEW_SAMPLES = 1 << 27


def analysis_config(window: int, lag: int, q: float = 0.0, mode: str = "sliding", activity: str = "s2",
                    max_lag: int | None = None, noise_floor: bool = True, base: DaemonConfig | None = None
                    ) -> DaemonConfig:
    """The config ``analyze`` measures with: ``base``'s (the daemon's: its camera's noise, its
    regions' thresholds) or a default one, its ``[estimator]`` with the window, lag, q (0 for a
    map formed at q = 0: Fujii), mode and activity analysed (validated: a lag too long is refused as in a config)."""
    if base is None:
        base = validate(DaemonConfig, {"camera": {"uri": "sim:default"}}, "<analyze>")
    record = registry.REGISTRY.get(activity)  # an unknown name is refused by the validation below
    asked = {"window": window, "lag": lag, "q": q if record is None else record.q_for(q), "mode": mode,
             "activity": activity, "max_lag": max_lag, "noise_floor": noise_floor}
    estimator = validate(EstimatorSection, {**base.estimator.model_dump(exclude_unset=True), **asked}, "estimator")
    return base.model_copy(update={"estimator": estimator})


def _view_patch(regions: Mapping[str, np.ndarray], window: int, config: DaemonConfig) -> int | None:
    """The noise patch of a timeline asked for the regions' every pixel: None (every pixel) while the
    regions' boxes over the patch window hold at most REGION_VIEW_SAMPLES pixel-frames, else the
    daemon's patch (``estimator.noise_patch``): the window of a whole large frame would double the
    timeline's memory (the ``noise_view`` column names the pixels judged)."""
    boxes = sum(int(np.prod([len(np.flatnonzero(mask.any(axis=axis))) for axis in (1, 0)]))
                for mask in regions.values())
    return None if min(window, MAX_PATCH_FRAMES) * boxes <= REGION_VIEW_SAMPLES else config.estimator.noise_patch


def histogram_map(engine: SlidingWindow, name: str) -> np.ndarray:
    """The one map ``name`` of the engine's window, float64 (H, W): formed from a live view of its
    sums, alone (``engine.maps`` forms every map of its fused pass: S1, S2, S3 and σ, four
    whole-frame float64 arrays where the histogram needs one). The same values as
    ``engine.maps((name,))[name]`` (the same per-pixel formula; tested)."""
    return maps_from(engine.snapshot((name,), live=True))[name]


def _noise_cells(reading: RegionReading | None) -> tuple:
    """mean_intensity … noise_view of one region's reading (NaN / "off" without the noise floor)."""
    if reading is None or reading.signal is None:
        return (NAN, "off", NAN, NAN, NAN, reading.estimator if reading else "", NAN if reading is None or
                reading.activity is None else reading.activity, NAN, reading.view if reading else "")
    signal = reading.signal
    return (signal.mean, signal.signal, *(reading.above.get(name, NAN) for name in PAPER), reading.estimator,
            NAN if reading.activity is None else reading.activity,
            reading.floors.get(reading.estimator, NAN) if reading.estimator != "tau_c" else NAN, reading.view)


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
    kinetics: bool = False  # the kinetics' columns last (measurement.kinetics.COLUMNS)
    stages: bool = False  # then the drying stages' (measurement.stages.COLUMNS; [[kinetics.stages]])

    @property
    def columns(self) -> tuple[str, ...]:
        """The rows' columns: COLUMNS, then one per descriptor, then the kinetics' and the stages' (when on)."""
        return (COLUMNS + self.descriptors + (region_kinetics.COLUMNS if self.kinetics else ())
                + (region_stages.COLUMNS if self.stages else ()))

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
             descriptors: Sequence[str] = (), band_split: float | None = None, q: float = 0.0,
             activity: str = "s2", noise_patch: int | None = None, config: DaemonConfig | None = None,
             kinetics: KineticsSection | None = None) -> Timeline:
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
    The samples are the measurement core's readings (:class:`edgedsm.measurement.Core`, the daemon's
    engine, reduction and judge): with ``with_noise`` each region's light, its S1, S2, S3 above the
    camera's noise floor (docs/noise.md) and its ``activity`` (the column ``activity``: the value the
    daemon's thresholds judge, above the floor of ``activity``'s map, NaN while held) are judged on
    every pixel of the region (``noise_patch`` None, the column ``noise_view`` "region"; the daemon's
    patch beyond REGION_VIEW_SAMPLES pixel-frames) or, as the daemon does, on a square of
    ``noise_patch`` pixels at its centre; ``noise_model`` (a
    datasheet's), else the last model the frames gave. The above-noise columns read NaN while there
    is none, the signal column "off" without ``with_noise``. ``config``: the daemon config whose
    camera and regions' thresholds the judge takes (window, lag, ``q``, mode and ``activity`` as
    given here). ``descriptors``: some of :data:`DESCRIPTORS`, whose region means follow as columns
    (the histogram may be of one of them); ``band_split``: the bands' split in Hz (of ``dt``),
    default half the Nyquist frequency. ``kinetics``: each region's decorrelation time over decades
    (docs/kinetics.md), pushed every frame and read at each sample, as the last columns
    (``kinetics_tau_s``, ``kinetics_rate_hz``, ``kinetics_status``, ``kinetics_bound_s``); with its
    ``stages``, the stage each region reached and the time to the next (measurement.stages, the
    daemon's code, stepped at each sample on the timeline's clock).
    """
    if every < 1:
        raise EstimatorError(f"the sampling step must be >= 1 frame, got {every}")
    if not regions:
        raise EstimatorError("no region to follow")
    if unknown := [name for name in descriptors if name not in DESCRIPTORS]:
        raise EstimatorError(f"the timeline streams the descriptors {', '.join(DESCRIPTORS)}, not {unknown}")
    extra = tuple(name for name in DESCRIPTORS if name in descriptors)
    if histogram_estimator not in (*PAPER, *extra):
        raise EstimatorError(f"histogram estimator must be one of {', '.join((*PAPER, *extra))}, "
                             f"got {histogram_estimator!r}")
    stages = region_stages.KineticsStages(kinetics, list(regions)) if kinetics is not None and kinetics.stages else None
    result = Timeline(dt=dt, max_lag=max_lag, histogram_estimator=histogram_estimator, descriptors=extra,
                      kinetics=kinetics is not None, stages=stages is not None)
    if mode is None:
        mode = "tumbling" if every % window == 0 else "sliding"
    settings = analysis_config(window, lag, q, mode, activity if activity != "tau_c" else "s3",
                               max_lag=max_lag if with_tau else None, noise_floor=with_noise, base=config)
    if kinetics is not None:
        settings = settings.model_copy(update={"kinetics": kinetics.model_copy(update={"enabled": True})})
    core: Core | None = None
    pooled: TumblingRegionTau | None = None  # tumbling: the regions' τc without per-pixel lag products
    count = 0
    for index, frame in enumerate(frames):
        if core is None:
            depth = bits or 8 * frame.dtype.itemsize
            in_engine = with_tau and (mode != "tumbling" or int64_problem(frame.shape, window, depth) is not None)
            patch = noise_patch if noise_patch is not None else _view_patch(regions, window, settings)
            spec = EngineSpec.of_sections(settings.estimator, tau_c=in_engine, dt=dt, band_split=band_split,
                                           extra=extra)
            core = Core(settings, regions, patch=patch, floored=PAPER, dt=dt, spec=spec)
            if noise_model is not None:
                core.judgement.judge.keeper.model = noise_model
            if with_tau and not in_engine:
                pooled = TumblingRegionTau(frame.shape, regions, window, max_lag, depth)
        core.push(frame, bits)
        if pooled is not None:
            pooled.push(frame)
        count = index + 1
        if not core.ready or (index - (window - 1)) % every:
            continue
        time = index * dt if times_s is None else float(times_s[index])
        readings = core.read(time).readings
        staged = {} if stages is None else stages.step(time, {name: r.kinetics for name, r in readings.items()
                                                               if r.kinetics is not None}, float)[0]
        assert core.engine is not None
        for name in regions:
            reading = readings.get(name)
            values = reading.values if reading is not None else {}
            if with_tau:
                tau: TauC = pooled.last[name] if pooled is not None and pooled.last else core.fits[name]
                taus = (float(tau.tau), float(tau.tau) * dt, STATUS_NAMES[int(tau.status)])
            else:
                taus = (NAN, NAN, "off")
            result.rows.append((index, time, name, *(values.get(key, NAN) for key in PAPER), *taus,
                                *_noise_cells(reading), *(values.get(key, NAN) for key in extra),
                                *(region_kinetics.cells(reading.kinetics if reading else None) if kinetics else ()),
                                *(region_stages.cells(staged.get(name)) if stages is not None else ())))
        values = histogram_map(core.engine, histogram_estimator)
        if histogram_range is None:  # in place: the histogram does not depend on the values' order
            top = 1.25 * float(np.percentile(values, 99.5, overwrite_input=True))
            histogram_range = (0.0, top if top > 0 else 1.0)
        density, edges = np.histogram(values, bins=bins, range=histogram_range, density=True)
        result.histograms.append(density)
        result.histogram_edges = edges
        result.sample_frames.append(index)
        result.sample_times.append(time)
        del values  # the next sample's map is not allocated beside this one
    if not result.rows:
        raise EstimatorError(f"{count} frames do not fill one window of N = {window}")
    return result
