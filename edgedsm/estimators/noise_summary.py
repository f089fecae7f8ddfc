"""One region's activity against the camera's noise (docs/noise.md): the estimator's noise floor,
its value above the floor with a verdict, and the signal quality, from a window of frames.

The composition :func:`region_noise` is what ``edgedsm analyze --json`` reports (``noise_floor``,
``above_noise``, ``signal``); the formulas are in :mod:`~edgedsm.estimators.noise_floor` and
:mod:`~edgedsm.estimators.signal_quality`. Pure: arrays in, a dataclass out.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass

import numpy as np

from edgedsm.errors import EstimatorError
from edgedsm.estimators import noise, noise_floor, signal_quality
from edgedsm.estimators.descriptors import compute
from edgedsm.estimators.noise import NoiseModel
from edgedsm.estimators.noise_floor import AboveNoise, Floor
from edgedsm.estimators.registry import REGISTRY, Record, load, with_floor

#: The registry's maps with a noise floor (those registered at import; the checks below read the
#: registry itself).
ESTIMATORS = with_floor()
#: Those judged above the noise through the signal's share of the variance, per window (S3, the contrast).
SHARED = tuple(name for name in ESTIMATORS if REGISTRY[name].shared_floor)


def _floored(estimator: str) -> Record:
    """The record of ``estimator``, which must have a noise floor."""
    record = REGISTRY.get(estimator)
    if record is None or record.floor is None:
        raise EstimatorError(f"estimator must be one of {', '.join(with_floor())}, got {estimator!r}")
    return record


@dataclass(frozen=True)
class RegionNoise:
    """The region's estimate, its floor and what is above it (the estimator's units), the
    verdicts, and the model used; ``model_error`` says why no model could be had (then only the
    light is judged)."""

    estimator: str
    estimate: float
    noise_floor: float | None
    above_noise: float | None
    spread: float | None
    verdict: str | None
    signal: str
    dark_fraction: float
    saturated_fraction: float
    speckle_contrast: float
    model: dict[str, float | str | bool] | None
    model_error: str | None = None

    def as_dict(self) -> dict[str, object]:
        return asdict(self)


def full_scale(frames: np.ndarray, bits: int | None) -> float:
    """The camera's full scale in DN: 2^bits - 1 for integer frames, else their maximum."""
    if bits is not None:
        return float(2**bits - 1)
    if np.issubdtype(frames.dtype, np.integer):
        return float(np.iinfo(frames.dtype).max)
    return float(np.max(frames)) or 1.0


@dataclass(frozen=True)
class RegionFloor:
    """What a region's above-noise activity needs beside its current estimates: the judged
    estimator's noise floor (for S3, S1's floor) and, for S3 and the contrast, the signal's share
    of the variance.
    Taken from one window, it turns later estimates into above-noise values (:func:`above_of`)
    without the frames."""

    estimator: str
    floor: Floor
    share: AboveNoise | None = None
    noise_variance: float | None = None  # S3, contrast: a static pixel's variance σ̄_n² (DN²), for the share


def region_noise(frames: np.ndarray, estimate_map: np.ndarray | None, estimator: str, lag: int, *, q: float = 0.0,
                 model: NoiseModel | None = None, mask: np.ndarray | None = None,
                 bits: int | None = None, estimates: Mapping[str, float] | None = None) -> RegionNoise:
    """The noise summary of the (N, H, W) ``frames`` window whose ``estimator`` map ("s1", "s2"
    or "s3" at ``lag``) is ``estimate_map``, over the boolean ``mask`` (default: all pixels).
    ``estimates``: the region's values instead of the map's means (``estimator``'s, and "s1" for
    S3), when ``frames`` is only a sample of the region (the daemon's patch): the floor is that of
    the sample's pixel means.
    ``model``: the camera's noise model; None estimates it from the frames
    (:func:`~edgedsm.estimators.noise.from_frames`), which fails on activity faster than a few
    frames: then ``model_error`` says so and only the light is judged."""
    stack = np.asarray(frames)
    if stack.ndim != 3:
        raise EstimatorError(f"frames must be a (N, H, W) stack, got shape {stack.shape}")
    record = _floored(estimator)
    region = np.ones(stack.shape[1:], bool) if mask is None else np.asarray(mask, bool)
    top = full_scale(stack, bits)
    values = dict(estimates) if estimates is not None else {}
    if estimator not in values:
        if estimate_map is None:
            raise EstimatorError(f"no {estimator} estimate: give its map or its region value")
        values[estimator] = float(np.asarray(estimate_map, np.float64)[region].mean())
    for other in record.above_inputs:  # S3 above the noise needs S1's value too
        if other not in values:
            values[other] = float(compute(other, stack, lag=lag, q=q)[region].mean())
    estimate = values[estimator]
    error = None
    if model is None:
        try:
            model = noise.from_frames(stack, saturation=top, mask=region)
        except EstimatorError as exc:
            error = str(exc)
    if model is None:
        light = signal_quality.light_stats(stack, noise.from_datasheet(0.0, 0.0), top, region)
        quality = signal_quality.signal_quality(light)
        return RegionNoise(estimator, estimate, None, None, None, None, quality.verdict, quality.dark_fraction,
                           quality.saturated_fraction, light.speckle_contrast, None, error)
    above = above_of(region_floor(stack, estimator, lag, model, q=q, mask=region, top=top), values)
    light = signal_quality.light_stats(stack, model, top, region)
    quality = signal_quality.signal_quality(light, above)
    return RegionNoise(estimator, estimate, above.floor, above.value, above.spread, above.verdict, quality.verdict,
                       quality.dark_fraction, quality.saturated_fraction, light.speckle_contrast,
                       model_summary(model))


def model_summary(model: NoiseModel) -> dict[str, float | str | bool]:
    """The model as reported: its source and parameters."""
    return {"source": model.source, "gain": model.gain, "dark_mean": model.dark_mean,
            "dark_variance": model.dark_variance, "relative_error": model.relative_error}


def region_floor(frames: np.ndarray, estimator: str, lag: int, model: NoiseModel, *, q: float = 0.0,
                 mask: np.ndarray | None = None, top: float = math.inf,
                 previous: RegionFloor | None = None) -> RegionFloor:
    """The :class:`RegionFloor` of ``estimator`` for the (N, H, W) window ``frames`` over ``mask``:
    the floor follows the pixels' window means (docs/noise.md), S3's share their mean variance.
    ``previous``: this region's floor from an earlier window with the same model and about the
    same pixel means, kept as it is (the costly part); only the share (S3, contrast) follows this window."""
    stack = np.asarray(frames)
    region = np.ones(stack.shape[1:], bool) if mask is None else np.asarray(mask, bool)
    n = stack.shape[0]
    record = _floored(estimator)
    if previous is not None and previous.estimator != estimator:
        raise EstimatorError(f"previous floor is {previous.estimator}'s, not {estimator}'s")
    if previous is not None and not record.shared_floor:
        return previous
    means = stack.mean(axis=0, dtype=np.float64)[region]  # per pixel along time: no copy of the region
    assert record.floor is not None
    floor_of = load(record.floor)  # the record's noise_floor function, with the arguments it names
    args = {name: value for name, value in (("lag", lag), ("q", q)) if name in record.floor_args}
    if not record.shared_floor:
        return RegionFloor(estimator, floor_of(model, means, n, top=top, **args))
    if previous is not None and previous.noise_variance is not None:
        floor, static = previous.floor, previous.noise_variance
    else:
        floor, static = floor_of(model, means, n, top=top, **args)
    # S3 and the contrast of the signal alone need the region's mean window variance (Eq. 3-4)
    variance = float(stack.var(axis=0, dtype=np.float64)[region].mean())
    share = noise_floor.signal_share(model, means, variance, n, top=top, noise_variance=static)
    return RegionFloor(estimator, floor, share, static)


def above_of(floor: RegionFloor, estimates: Mapping[str, float]) -> AboveNoise:
    """The region's activity above the noise from its current ``estimates`` (the judged
    estimator's region mean; for S3 also "s1") and a :class:`RegionFloor`."""
    record = _floored(floor.estimator)
    if not record.shared_floor:
        return noise_floor.above_noise(estimates[floor.estimator], floor.floor)
    assert floor.share is not None and record.above is not None
    value = load(record.above)(*(estimates[name] for name in record.above_inputs), floor.floor, floor.share)
    if not math.isfinite(value.value):
        raise EstimatorError(f"{record.label} above noise is not finite")
    return value
