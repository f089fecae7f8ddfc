"""The measurement core: frames (or the engine's region statistics) in, per region the values of
every map, their noise floors, the value the thresholds judge, the signal quality and the drying
state with its transitions out (docs/architecture.md, "The measurement core").

Two halves, split where the daemon splits its threads:

- :class:`Judgement` (the daemon's evaluator thread): the signal judge
  (:class:`~edgedsm.measurement.judge.SignalJudge`) and the drying-state machines
  (:class:`~edgedsm.drying.DryingMonitor`). From every region's map means (``estimates``), its
  plain activity (the activity map's mean, or τc in seconds) and, on the stats cadence, its noise
  patch window, it gives the judged ``activity`` (above the floor, plain while no model is known,
  None while the light cannot be judged), the signal and the transitions. :meth:`Judgement.evaluate`
  is the one order of those steps; the daemon's evaluator runs the same three steps with its lock
  around the state machines' (:meth:`assess`, :meth:`judged`, :meth:`step`).
- :class:`Core` (one thread: ``analyze``, ``analyze --timeline``, ``tune``): the engine from the
  config's :class:`~edgedsm.measurement.spec.EngineSpec`, the regions reduced from its live sums as
  the daemon's pipeline thread reduces them (:func:`~edgedsm.estimators.region_stats.region_moments`),
  each region's noise patches, and a :class:`Judgement`.

Which pixels the noise is judged on is named in every reading (``view``): the daemon judges a patch
of ``estimator.noise_patch``² pixels at each region's centre (its cost bound); ``analyze`` judges
every pixel of the region (``view`` "region"), or the daemon's patch when asked. The map means are
always the whole region's. For the same region, frames and view, every user gets the same numbers.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from edgedsm.config import DaemonConfig
from edgedsm.config.devices import CameraNoiseSection
from edgedsm.config.estimator import EstimatorSection
from edgedsm.config.regions import RegionSettings
from edgedsm.drying import DryingMonitor, Transition
from edgedsm.errors import EstimatorError
from edgedsm.estimators import SlidingWindow
from edgedsm.estimators.correlation_time import TauC
from edgedsm.estimators.noise import NoiseModel
from edgedsm.estimators.noise_floor import AboveNoise
from edgedsm.estimators.noise_summary import full_scale
from edgedsm.estimators.region_box import RegionBox
from edgedsm.estimators.region_stats import Moments, RegionLayout, RegionPlan, region_moments
from edgedsm.estimators.snapshot import TauSnapshot
from edgedsm.estimators.streaming import PARALLEL_MIN_PIXELS
from edgedsm.measurement.judge import SignalJudge, SignalWarning
from edgedsm.measurement.kinetics import KineticsRegions, judged_seconds
from edgedsm.measurement.spec import EngineSpec
from edgedsm.measurement.tau import in_seconds, region_fits
from edgedsm.messages import RegionKinetics, RegionSignal
from edgedsm.noise_patches import MAX_PATCH_FRAMES, NoisePatches, PatchWindow, patch_of

#: ``view`` of a reading whose noise is judged on every pixel of the region
REGION_VIEW = "region"


def reduce(engine: SlidingWindow, layout: RegionLayout, maps: Sequence[str], spread: bool = False
           ) -> dict[str, dict[str, Moments]]:
    """Every region's moments of ``maps`` from the engine's live sums, between two pushes on the
    thread that pushes (no copy, no float maps): the daemon's pipeline thread and :class:`Core`
    reduce through this one function; ``spread``: the deviations and percentile samples too."""
    return region_moments(engine.snapshot(maps, live=True), layout, maps, spread=spread,
                          parallel=engine.shape[0] * engine.shape[1] >= PARALLEL_MIN_PIXELS)


def view_of(patch: int | None) -> str:
    """The name of the pixels the noise is judged on: the region, or a patch of ``patch``² px."""
    return REGION_VIEW if patch is None else f"patch {patch}x{patch} px at the region's centre"


@dataclass(frozen=True)
class RegionReading:
    """One region at one evaluation (units: each map's; τc in seconds)."""

    region: str
    view: str  # the pixels the noise floors and the signal come from (view_of)
    estimator: str  # what ``activity`` and ``plain`` are of: estimator.activity, or "tau_c"
    plain: float | None  # the region's plain statistic of ``estimator`` (its map's mean, or τc in s)
    activity: float | None  # what the thresholds judge: above the floor, the plain value, None: held
    values: dict[str, float]  # every map's region mean
    above: dict[str, float]  # each floored map's value above its floor (judge.floored and the judged one)
    floors: dict[str, float]  # their floors
    signal: RegionSignal | None  # None: no patch window judged yet, or the noise floor off
    state: str
    tau_c_s: float | None = None
    tau_c_status: str | None = None
    kinetics: RegionKinetics | None = None  # its decorrelation time (s), rate (Hz), status ([kinetics] on)


@dataclass
class Evaluation:
    """What one evaluation gave: warnings that began or cleared, transitions, readings by region."""

    warnings: list[SignalWarning] = field(default_factory=list)
    transitions: list[Transition] = field(default_factory=list)
    readings: dict[str, RegionReading] = field(default_factory=dict)


def step_states(monitor: DryingMonitor, now: float, judged: Mapping[str, float | None], ready: bool = True,
                fault: str | None = None) -> list[Transition]:
    """Step the state machines of ``monitor`` at ``now`` (s) with each region's judged value: the one
    way states are stepped, by the daemon (:meth:`Judgement.step`) and by ``tune``'s replay of a
    reference run (a region without a judged value, None: held, keeps its state)."""
    return monitor.step(now, {name: value for name, value in judged.items() if value is not None},
                        ready=ready, fault=fault)


class Judgement:
    """The signal judge and the drying-state machines of a config's regions (one thread)."""

    def __init__(self, estimator: EstimatorSection, regions: Sequence[RegionSettings] = (),
                 noise: CameraNoiseSection | None = None, t0: float = 0.0, floored: Sequence[str] = (),
                 view: str = REGION_VIEW) -> None:
        self.judge = SignalJudge(estimator, regions, noise, floored=floored)
        self.monitor = DryingMonitor({r.name: r.thresholds() for r in regions}, t0=t0)
        self.view = view

    @classmethod
    def of(cls, config: DaemonConfig, t0: float = 0.0, floored: Sequence[str] = (),
           view: str = REGION_VIEW) -> Judgement:
        """The judgement of a whole config's sections (``[estimator]``, ``[[regions]]``, ``[camera.noise]``)."""
        return cls(config.estimator, config.regions, config.camera.noise, t0, floored, view)

    @property
    def on(self) -> bool:
        """The noise floor is judged (``estimator.noise_floor``)."""
        return self.judge.on

    def assess(self, patches: Mapping[str, PatchWindow], estimates: Mapping[str, Mapping[str, float]]
               ) -> list[SignalWarning]:
        """The regions' signal and floors from their patch windows (none: nothing to assess)."""
        return self.judge.assess(patches, estimates) if self.on and patches else []

    def judged(self, plain: Mapping[str, float | None], estimates: Mapping[str, Mapping[str, float]]
               ) -> dict[str, float | None]:
        """What each region's state is judged on (:meth:`SignalJudge.judged`; plain without the floor)."""
        if not self.on:
            return dict(plain)
        return {name: self.judge.judged(name, value, estimates.get(name, {})) for name, value in plain.items()}

    def step(self, now: float, judged: Mapping[str, float | None], ready: bool = True,
             fault: str | None = None) -> list[Transition]:
        """Step every region's state machine (:func:`step_states`)."""
        return step_states(self.monitor, now, judged, ready, fault)

    def reset(self, now: float, why: str) -> list[Transition]:
        """Every region back to warming up (the judge's restart: :meth:`SignalJudge.restart`)."""
        return self.monitor.reset(now, why)

    def apply(self, regions: Sequence[RegionSettings]) -> None:
        """New thresholds for the running machines (states, dwell and trend kept); the regions'
        names are those running. (The judge's settings: :meth:`SignalJudge.apply`, on its thread.)"""
        thresholds = {region.name: region.thresholds() for region in regions}
        for name, machine in self.monitor.regions.items():
            machine.thresholds = thresholds[name]

    def estimator(self, region: str) -> str:
        activity = self.judge.estimator.activity
        return "tau_c" if self.judge.on_tau(region) and activity != "kinetics" else activity

    def reading(self, region: str, plain: float | None, judged: float | None, values: Mapping[str, float],
                tau: tuple[float, str] | None = None, kinetics: RegionKinetics | None = None) -> RegionReading:
        """The region's reading from its plain and judged value, its map means and τc."""
        above, floors = {}, {}
        if self.on:
            for name in dict.fromkeys((self.judge.floor_estimator(region), *self.judge.floored)):
                value = self.judge.above(region, name, values)
                if value is not None:
                    above[name], floors[name] = float(value.value), float(value.floor)
        machine = self.monitor.regions.get(region)
        return RegionReading(region, self.view, self.estimator(region), plain, judged, dict(values), above, floors,
                             self.judge.signals.get(region) if self.on else None,
                             machine.state.value if machine is not None else "unjudged",
                             *(tau if tau is not None else (None, None)), kinetics)

    def evaluate(self, now: float, plain: Mapping[str, float | None], estimates: Mapping[str, Mapping[str, float]],
                 patches: Mapping[str, PatchWindow] | None = None, ready: bool = True, fault: str | None = None,
                 taus: Mapping[str, tuple[float, str]] | None = None,
                 kinetics: Mapping[str, RegionKinetics] | None = None) -> Evaluation:
        """One evaluation in the daemon's order: assess the patches (when given), judge, step."""
        warnings = self.assess(patches or {}, estimates)
        judged = self.judged(plain, estimates)
        transitions = self.step(now, judged, ready, fault)
        taus, kinetics = taus or {}, kinetics or {}
        readings = {name: self.reading(name, plain.get(name), judged.get(name), estimates.get(name, {}),
                                       taus.get(name), kinetics.get(name)) for name in estimates}
        return Evaluation(warnings, transitions, readings)


class Core:
    """The engine, the regions and the judgement of one config over frames pushed one by one (one
    thread). ``regions``: boolean masks in the frames' shape; ``patch``: the side of the noise
    patch at each region's centre (None: every pixel of the region: ``view`` "region");
    ``floored``: maps whose floors the judge keeps beside the judged one; ``extra``: maps the engine
    keeps sums for beside the config's; ``dt``: the frame interval (s) of τc in seconds;
    ``companions``: more engines fed the same frames, whose maps' region means join the main
    engine's (``tune``'s Fujii at q = 0 beside S2 at the config's q, as two daemons would run)."""

    def __init__(self, config: DaemonConfig, regions: Mapping[str, np.ndarray], *, patch: int | None = None,
                 floored: Sequence[str] = (), extra: Sequence[str] = (), dt: float = 1.0,
                 spec: EngineSpec | None = None, t0: float = 0.0, companions: Sequence[EngineSpec] = ()) -> None:
        if not regions:
            raise EstimatorError("no region to measure")
        self.config = config
        self.spec = spec or EngineSpec.of_sections(config.estimator, tau_c=config.tau_c_on, extra=extra,
                                                   **config.band_args)
        self.companions = tuple(companions)
        self.masks = dict(regions)
        self.patch = patch
        self.dt = dt
        self.judgement = Judgement.of(config, t0=t0, floored=floored, view=view_of(patch))
        self.engine: SlidingWindow | None = None
        self._others: list[tuple[SlidingWindow, tuple[str, ...]]] = []  # the companions' engines and maps
        self.patches: NoisePatches | None = None
        self._layout: RegionLayout | None = None
        self._pixels: dict[str, np.ndarray] = {}  # each region's flat indices in the engine's frame
        self._tau_sums: TauSnapshot | None = None  # the last τc snapshot, its arrays reused
        #: each region's τc fit (frames, status) at the last :meth:`read` (empty without τc)
        self.fits: dict[str, TauC] = {}
        #: each region's kinetics (``[kinetics]`` on: :mod:`edgedsm.measurement.kinetics`), fed every frame
        self.kinetics: KineticsRegions | None = None

    def _prepare(self, frame: np.ndarray, bits: int | None) -> None:
        shape = frame.shape
        for name, mask in self.masks.items():
            if mask.shape != shape:
                raise EstimatorError(f"region {name!r} is {mask.shape[1]}x{mask.shape[0]}, "
                                     f"the frames {shape[1]}x{shape[0]}")
        boxes = {name: RegionBox.of(mask) for name, mask in self.masks.items()}
        self.engine = self.spec.engine(shape, bits, threads=None)
        self._others = [(spec.engine(shape, bits, threads=None), spec.maps) for spec in self.companions]
        self._layout = RegionLayout.of({name: RegionPlan.of(box, shape) for name, box in boxes.items()})
        self._pixels = {name: np.flatnonzero(mask) for name, mask in self.masks.items()}
        if self.config.kinetics.enabled:
            # the datasheet's model ([camera.noise], or the one a caller gave the judge before the first frame)
            self.kinetics = KineticsRegions(self.config.kinetics, self.masks, self.judgement.judge.keeper.model,
                                            top=float(2**bits - 1) if bits else None)
        if self.judgement.on:
            side = self.patch if self.patch is not None else max(shape)  # a patch the region's box: all of it
            self.patches = NoisePatches(boxes, min(self.spec.window, MAX_PATCH_FRAMES), side, frame.dtype, bits)

    def push(self, frame: np.ndarray, bits: int | None = None) -> None:
        """One frame into the engine and the noise patches (the first fixes the shape)."""
        if self.engine is None:
            self._prepare(frame, bits)
        assert self.engine is not None
        self.engine.push(frame)
        for other, _ in self._others:
            other.push(frame)
        if self.patches is not None:
            self.patches.push(frame)
        if self.kinetics is not None:
            self.kinetics.push(frame, self.dt)

    @property
    def ready(self) -> bool:
        return self.engine is not None and self.engine.ready

    def estimates(self) -> dict[str, dict[str, float]]:
        """Every region's mean of every map, from the engine's live sums (the daemon's reduction)."""
        assert self.engine is not None and self._layout is not None
        out: dict[str, dict[str, float]] = {}
        for engine, maps in ((self.engine, self.spec.maps), *self._others):
            for region, per_map in reduce(engine, self._layout, maps).items():
                out.setdefault(region, {}).update({key: m.mean for key, m in per_map.items()})
        return out

    def taus(self) -> dict[str, tuple[float, str]]:
        """Each region's τc in seconds from its pooled correlations, with its status (none without τc):
        the daemon's computation (:mod:`edgedsm.measurement.tau`) on a snapshot of the live sums;
        the fits in frames stay in :attr:`fits`."""
        if self.engine is None or not self.spec.tau_c:
            return {}
        self._tau_sums = self.engine.tau_snapshot(into=self._tau_sums)
        self.fits = region_fits(self._tau_sums, self._pixels)
        return {name: (tau.tau_c_s, tau.status) for name, tau in
                ((name, in_seconds(fit, self.dt)) for name, fit in self.fits.items())}

    def read(self, now: float, assess: bool = True) -> Evaluation:
        """Evaluate now (the window full): the readings of every region and the transitions;
        ``assess``: judge the noise patches too (the daemon's stats cadence), else the floors last
        found turn the new means into judged values (its states cadence)."""
        if not self.ready:
            raise EstimatorError("the window is not full yet")
        estimates = self.estimates()
        taus = self.taus()
        activity = self.config.estimator.activity
        plain = {name: (taus[name][0] if self.judgement.judge.on_tau(name) and name in taus
                        else values.get(activity)) for name, values in estimates.items()}
        kinetics = self.kinetics.read(self.dt) if self.kinetics is not None else {}
        if activity == "kinetics":  # judged as τc is: τ in s, or its bound (measurement.kinetics)
            plain = {name: judged_seconds(kinetics.get(name)) for name in plain}
        patches = self.patches.take() if assess and self.patches is not None and self.patches.full else {}
        return self.judgement.evaluate(now, plain, estimates, patches, ready=True, taus=taus, kinetics=kinetics)


def judge_window(config: DaemonConfig, frames: np.ndarray, values: Mapping[str, float], *, bits: int | None = None,
                mask: np.ndarray | None = None, patch: int | None = None, region: str = "frame",
                model: NoiseModel | None = None) -> tuple[RegionReading, AboveNoise | None, Judgement]:
    """One region's reading from one (N, H, W) window of ``frames`` whose map means are ``values``
    (``analyze``'s map: a batch map's mean), judged as :class:`Core` judges a sample with the same
    frames in its patch: ``mask`` the region (default every pixel), ``patch`` the side of the
    square at its centre (None: all of it), ``model`` a datasheet's (default: from the frames).
    Returns the reading, the judged map's value above its floor with its verdict, and the judgement
    (its judge's model)."""
    stack = np.asarray(frames)
    region_mask = np.ones(stack.shape[1:], bool) if mask is None else np.asarray(mask, bool)
    box = RegionBox.of(region_mask)
    rows, cols, inside = patch_of(box, patch if patch is not None else max(stack.shape[1:]))
    window = PatchWindow(np.ascontiguousarray(stack[:, rows, cols]), inside, full_scale(stack, bits))
    activity = config.estimator.activity
    judgement = Judgement.of(config, view=view_of(patch))
    if model is not None:
        judgement.judge.keeper.model = model
    evaluation = judgement.evaluate(0.0, {region: values.get(activity)}, {region: dict(values)}, {region: window})
    return (evaluation.readings[region], judgement.judge.above(region, activity, values) if judgement.on else None,
            judgement)
