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
from edgedsm.estimators.batch import s1
from edgedsm.estimators.noise import NoiseModel
from edgedsm.estimators.noise_floor import AboveNoise, Floor

ESTIMATORS = ("s1", "s2", "s3", "fujii", "im", "gd", "contrast")  # those with a noise floor
SHARED = ("s3", "contrast")  # above the noise through the signal's share of the variance, per window


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
    if estimator not in ESTIMATORS:
        raise EstimatorError(f"estimator must be one of {', '.join(ESTIMATORS)}, got {estimator!r}")
    region = np.ones(stack.shape[1:], bool) if mask is None else np.asarray(mask, bool)
    top = full_scale(stack, bits)
    values = dict(estimates) if estimates is not None else {}
    if estimator not in values:
        if estimate_map is None:
            raise EstimatorError(f"no {estimator} estimate: give its map or its region value")
        values[estimator] = float(np.asarray(estimate_map, np.float64)[region].mean())
    if estimator == "s3" and "s1" not in values:
        values["s1"] = float(s1(stack, lag)[region].mean())
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
    if estimator not in ESTIMATORS:
        raise EstimatorError(f"estimator must be one of {', '.join(ESTIMATORS)}, got {estimator!r}")
    if previous is not None and previous.estimator != estimator:
        raise EstimatorError(f"previous floor is {previous.estimator}'s, not {estimator}'s")
    if previous is not None and estimator not in SHARED:
        return previous
    means = stack.mean(axis=0, dtype=np.float64)[region]  # per pixel along time: no copy of the region
    if estimator == "s2":
        return RegionFloor(estimator, noise_floor.s2_floor(model, means, n, lag, q=q, top=top))
    if estimator == "s1":
        return RegionFloor(estimator, noise_floor.s1_floor(model, means, n, lag, top=top))
    if estimator == "fujii":
        return RegionFloor(estimator, noise_floor.fujii_floor(model, means, n, lag, top=top))
    if estimator == "im":
        return RegionFloor(estimator, noise_floor.im_floor(model, means, n, lag, top=top))
    if estimator == "gd":
        return RegionFloor(estimator, noise_floor.gd_floor(model, means, n, top=top))
    if previous is not None and previous.noise_variance is not None:
        floor, static = previous.floor, previous.noise_variance
    elif estimator == "contrast":
        floor, static = noise_floor.contrast_floor_and_static_variance(model, means, n, top=top)
    else:
        floor, static = noise_floor.s1_floor_and_static_variance(model, means, n, lag, top=top)
    # S3 and the contrast of the signal alone need the region's mean window variance (Eq. 3-4)
    variance = float(stack.var(axis=0, dtype=np.float64)[region].mean())
    share = noise_floor.signal_share(model, means, variance, n, top=top, noise_variance=static)
    return RegionFloor(estimator, floor, share, static)


def above_of(floor: RegionFloor, estimates: Mapping[str, float]) -> AboveNoise:
    """The region's activity above the noise from its current ``estimates`` (the judged
    estimator's region mean; for S3 also "s1") and a :class:`RegionFloor`."""
    if floor.estimator not in SHARED:
        return noise_floor.above_noise(estimates[floor.estimator], floor.floor)
    assert floor.share is not None
    if floor.estimator == "contrast":
        return noise_floor.contrast_signal(estimates["contrast"], floor.floor, floor.share)
    value = noise_floor.s3_signal(estimates["s3"], estimates["s1"], floor.floor, floor.share)
    if not math.isfinite(value.value):
        raise EstimatorError("S3 above noise is not finite")
    return value
