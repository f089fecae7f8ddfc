"""Each region's light and its activity against the camera's noise (docs/noise.md;
``estimator.noise_floor``): the signal judge of the measurement core, run on the daemon's evaluator
thread and, on the same patches, by ``analyze`` and ``tune``.

On the stats cadence the judge takes the regions' patch windows (:mod:`edgedsm.noise_patches`)
and the regions' estimates from the engine, and finds per region the signal quality and the
judged estimator's noise floor. Between two stats evaluations the floor found last turns each
new estimate into its above-noise value (no frames needed). The drying states are judged on that
value; a region whose light is dark, saturated or not speckle is not judged at all (it keeps its
state) and raises one warning, cleared when the light recovers. A change of mean intensity by
more than ``estimator.intensity_change`` since the window first filled is a warning of its own.

The noise model comes from ``[camera.noise]`` (a datasheet), else from the frames themselves
(:func:`~edgedsm.estimators.noise.from_frames`): that fails while the activity decorrelates
within a few frames (a wet film), and the last model found is kept, the camera being the same.
Until there is one the states are judged on the plain activity, whose floor is then small
beside it.

Beside the judged estimator's floor, a judge may keep the floors of more maps (``floored``: the
timeline's S1-S3 columns, tune's candidates), from the same patches and model: each map's value
above its floor is then :meth:`SignalJudge.above`, and what a region would be judged on were that
map the activity, :meth:`SignalJudge.judged_as`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from edgedsm.config import DaemonConfig
from edgedsm.config.devices import CameraNoiseSection
from edgedsm.config.estimator import EstimatorSection
from edgedsm.config.regions import RegionSettings
from edgedsm.errors import EstimatorError
from edgedsm.estimators import noise, registry, signal_quality
from edgedsm.estimators.noise import NoiseModel
from edgedsm.estimators.noise_floor import AboveNoise
from edgedsm.estimators.noise_summary import RegionFloor, above_of, region_floor, region_noise
from edgedsm.messages import RegionSignal
from edgedsm.noise_patches import PatchWindow

#: The maps with a noise floor (the registry's): the others are judged as they are.
FLOORED = registry.with_floor()

#: Floors (and a model from the frames) are computed afresh at least every this many assessments
#: (a minute at the default 5 s stats interval): they change as slowly as the light, and one costs
#: ~30-100 ms per 64² patch against ~2 ms for the light statistics.
REFRESH_EVERY = 12
#: A floor is kept while the patch's mean intensity stays within this share of its value then
#: (the floor scales as √μ under shot noise: 1 % of floor for 2 % of mean).
FLOOR_KEPT = 0.02

#: Verdicts under which a region is not judged (it keeps its state): its light cannot be timed.
HOLD = (signal_quality.DARK, signal_quality.SATURATED, signal_quality.NOT_SPECKLE)


@dataclass(frozen=True)
class SignalWarning:
    """A region's signal warning that began (``active``) or cleared."""

    region: str
    reason: str
    active: bool
    holds: bool = False  # the region's state is held while it lasts


def hold_reason(signal: RegionSignal) -> str | None:
    """Why a region's light cannot be judged, in words; None when it can."""
    if signal.signal == signal_quality.SATURATED:
        return f"signal saturated: {signal.saturated_fraction:.0%} of the pixels reach full scale"
    if signal.signal == signal_quality.DARK:
        return f"signal dark: {signal.dark_fraction:.0%} of the pixels dark (mean {signal.mean:.3g} grey levels)"
    if signal.signal == signal_quality.NOT_SPECKLE:
        return (f"signal not speckle: spatial contrast {signal.speckle_contrast:.2g} (out of focus or aperture "
                "too wide)")
    return None


def change_reason(ratio: float, factor: float) -> str | None:
    """The intensity-change warning for ``ratio`` = mean now / mean at the window's first fill."""
    if ratio * factor < 1.0:
        return f"mean intensity fell {1.0 / ratio:.3g}× since the window first filled"
    if ratio > factor:
        return f"mean intensity rose {ratio:.3g}× since the window first filled"
    return None


class ModelKeeper:
    """The camera's noise model: the datasheet's, else the best the patches' frames give (looked for
    at the first round of patches, then every REFRESH_EVERY rounds; a new estimate replaces the
    last, as the camera's gain may have been changed; a failed one keeps it). One keeper may
    serve several judges: a round of patches seen by one is not looked at again by the next."""

    def __init__(self, datasheet: NoiseModel | None) -> None:
        self.model = datasheet
        self._rounds = 0
        self._tried: int | None = None  # the round that last estimated a model from the frames
        self._seen: Mapping[str, PatchWindow] | None = None
        self.error: str | None = None  # why the last estimate from the frames failed (None: it did not)

    def see(self, patches: Mapping[str, PatchWindow]) -> None:
        if patches is self._seen:
            return
        self._seen = patches
        self._rounds += 1
        estimating = self.model is None or self.model.source == "frames"
        if estimating and (self._tried is None or self._rounds - self._tried >= REFRESH_EVERY):
            self._tried = self._rounds
            self._estimate(patches)

    def _estimate(self, patches: Mapping[str, PatchWindow]) -> None:
        best = None
        for patch in patches.values():
            try:
                model = noise.from_frames(patch.frames, saturation=patch.top, mask=patch.mask)
            except EstimatorError as exc:
                self.error = str(exc)
                continue  # activity too fast to separate, or too dark: keep what we have
            if best is None or model.relative_error < best.relative_error:
                best = model
        if best is not None:
            self.model, self.error = best, None


class SignalJudge:
    """Signal quality, noise floors and signal warnings of every region (one thread only: the
    daemon's evaluator thread). ``floored``: maps whose floors are kept beside the judged one's."""

    def __init__(self, estimator: EstimatorSection, regions: Sequence[RegionSettings] = (),
                 noise: CameraNoiseSection | None = None, keeper: ModelKeeper | None = None,
                 floored: Sequence[str] = ()) -> None:
        self.estimator = estimator
        self.noise = noise
        self._on_tau = frozenset(region.name for region in regions if region.on_tau)
        self.keeper = keeper or ModelKeeper(noise.model() if noise is not None else None)
        self.floored = tuple(name for name in floored if name in FLOORED)
        self._floors: dict[str, dict[str, RegionFloor]] = {}  # region -> map -> its floor
        self._basis: dict[tuple[str, str], tuple[NoiseModel | None, float, int]] = {}  # model, mean, assessment
        self._assessments = 0
        self.signals: dict[str, RegionSignal] = {}
        self._reference: dict[str, float] = {}  # mean intensity when the window first filled
        self._warnings: dict[str, dict[str, str]] = {}  # region -> kind -> active reason

    @property
    def model(self) -> NoiseModel | None:
        return self.keeper.model

    @property
    def on(self) -> bool:
        return self.estimator.noise_floor

    def restart(self) -> None:
        """A new measurement: the reference intensities and the floors are taken again (the model
        and the active warnings are kept: they clear when the light recovers)."""
        self._reference.clear()
        self._floors.clear()
        self.signals.clear()

    @classmethod
    def of(cls, config: DaemonConfig, keeper: ModelKeeper | None = None, floored: Sequence[str] = ()) -> SignalJudge:
        """The judge of a whole config's sections (``[estimator]``, ``[[regions]]``, ``[camera.noise]``)."""
        return cls(config.estimator, config.regions, config.camera.noise, keeper, floored)

    def apply(self, estimator: EstimatorSection, regions: Sequence[RegionSettings] = (),
              noise: CameraNoiseSection | None = None) -> None:
        """A reload's settings (a new datasheet replaces the model; the rest is kept)."""
        if noise != self.noise:
            self.keeper.model = noise.model() if noise is not None else None
            self._floors.clear()
        self.estimator, self.noise = estimator, noise
        self._on_tau = frozenset(region.name for region in regions if region.on_tau)

    def on_tau(self, region: str) -> bool:
        """Whether ``region`` is judged on τc (the activity, or its own τc thresholds)."""
        return self.estimator.activity == "tau_c" or region in self._on_tau

    def floor_estimator(self, region: str) -> str:
        """The estimator whose floor a region is judged against: the activity; S3 (for its signal
        share) for a region judged on τc."""
        return "s3" if self.on_tau(region) else self.estimator.activity

    def floor(self, region: str, estimator: str | None = None) -> RegionFloor | None:
        """The region's last floor of ``estimator`` (default: the one it is judged against)."""
        return self._floors.get(region, {}).get(estimator or self.floor_estimator(region))

    def above(self, region: str, estimator: str, estimates: Mapping[str, float]) -> AboveNoise | None:
        """``estimator``'s region value above its last floor (None: no floor, or a value it needs
        missing from ``estimates``: S3's and τc's need S1 too)."""
        floor = self.floor(region, estimator)
        if floor is None or estimator not in estimates or (floor.estimator == "s3" and "s1" not in estimates):
            return None
        return above_of(floor, estimates)

    def assess(self, patches: Mapping[str, PatchWindow], estimates: Mapping[str, Mapping[str, float]]
               ) -> list[SignalWarning]:
        """Judge every region with a patch window and its estimates ("s1", "s2", "s3", ... region
        means); returns the warnings that began or cleared."""
        est = self.estimator
        self._assessments += 1
        self.keeper.see(patches)
        changes: list[SignalWarning] = []
        for name, patch in patches.items():
            values = estimates.get(name, {})
            floor_estimator = self.floor_estimator(name)
            above = None
            # an activity without a noise floor (not FLOORED) is judged as it is
            for estimator in dict.fromkeys((floor_estimator, *self.floored)):
                if self.model is None or estimator not in FLOORED or not all(
                        key in values for key in (estimator, "s1")):
                    continue
                floor = region_floor(patch.frames, estimator, est.lag, self.model, q=est.q, mask=patch.mask,
                                     top=patch.top, previous=self._reusable(name, patch, estimator))
                if floor is not self.floor(name, estimator):
                    self._basis[name, estimator] = (self.model, patch.region_mean(), self._assessments)
                self._floors.setdefault(name, {})[estimator] = floor
                if estimator == floor_estimator:
                    above = above_of(floor, values)
                    if self.on_tau(name):  # τc's above-noise measure: the signal's share of the variance
                        assert floor.share is not None
                        above = floor.share
            light = signal_quality.light_stats(patch.frames, self.model or noise.from_datasheet(0.0, 0.0),
                                               patch.top, patch.mask)
            quality = signal_quality.signal_quality(light, above)
            reference = self._reference.setdefault(name, light.mean)
            ratio = light.mean / reference if reference > 0 else None
            signal = RegionSignal(
                signal=quality.verdict, mean=max(light.mean, 0.0), dark_fraction=quality.dark_fraction,
                saturated_fraction=quality.saturated_fraction, speckle_contrast=max(light.speckle_contrast, 0.0),
                noise_floor=None if above is None else above.floor,
                above_noise=None if above is None else above.value,
                above_noise_spread=None if above is None else above.spread,
                noise_model=None if self.model is None else self.model.source,
                intensity_change=ratio if ratio else None,
                reason=None if self.model is not None else "no noise model yet: give [camera.noise] or wait for "
                                                            "activity slower than a few frames")
            hold = hold_reason(signal)
            if hold is not None:
                signal = signal.model_copy(update={"reason": hold})
            self.signals[name] = signal
            changes += self._warn(name, "signal", hold)
            changes += self._warn(name, "intensity", change_reason(ratio, est.intensity_change) if ratio else None)
        return changes

    def held(self, region: str) -> bool:
        """The region's light cannot be judged now (dark, saturated, not speckle): its state is held."""
        signal = self.signals.get(region)
        return signal is not None and signal.signal in HOLD

    def judged(self, region: str, value: float | None, estimates: Mapping[str, float]) -> float | None:
        """What the region's drying state is judged on now, from its plain ``value`` (the activity's
        region mean, or its τc) and its ``estimates``: the activity above its floor (the plain value
        while no model is known, and for τc); None (held) while the light cannot be judged."""
        if self.on_tau(region):
            return None if self.held(region) else value
        return self.judged_as(region, self.floor_estimator(region), value, estimates)

    def judged_as(self, region: str, estimator: str, value: float | None, estimates: Mapping[str, float]
                  ) -> float | None:
        """What the region would be judged on were ``estimator`` its activity (its plain ``value``):
        above its floor when the judge keeps one, else the plain value; None while held."""
        if self.held(region):
            return None
        above = self.above(region, estimator, estimates) if value is not None else None
        return value if above is None else above.value

    def _reusable(self, region: str, patch: PatchWindow, estimator: str) -> RegionFloor | None:
        """The region's last floor of ``estimator`` when it still holds: same model, pixel means
        within FLOOR_KEPT of those it was computed from, computed within REFRESH_EVERY assessments."""
        floor, basis = self.floor(region, estimator), self._basis.get((region, estimator))
        if floor is None or basis is None:
            return None
        model, mean, when = basis
        now = patch.region_mean()
        if model is not self.model or self._assessments - when >= REFRESH_EVERY or abs(now - mean) > FLOOR_KEPT * mean:
            return None
        return floor

    def _warn(self, region: str, kind: str, reason: str | None) -> list[SignalWarning]:
        active = self._warnings.setdefault(region, {})
        if reason is None:
            if kind in active:
                return [SignalWarning(region, f"cleared: {active.pop(kind)}", False)]
            return []
        if kind in active:
            active[kind] = reason  # still on: not raised again
            return []
        active[kind] = reason
        return [SignalWarning(region, reason, True, holds=kind == "signal")]


def warm_up() -> None:
    """Run the judge's numeric path once on a small random window: its first call loads SciPy's
    filters and fills numpy's caches (about a second), which would otherwise fall on the first
    evaluation of a full window and hold the evaluator while the states are due."""
    rng = np.random.default_rng(0)
    speckle = rng.exponential(60.0, (16, 16))
    frames = np.clip(rng.poisson(speckle * rng.uniform(0.8, 1.2, (32, 1, 1))), 0, 255).astype(np.uint8)
    for estimator in ("s1", "s2", "s3"):  # SciPy and numpy's caches: the other floors share their paths
        for model in (None, noise.from_datasheet(0.5, 2.0)):
            region_noise(frames, None, estimator, 1, model=model, bits=8,
                         estimates={"s1": 5.0, "s2": 0.05, "s3": 1.0})
