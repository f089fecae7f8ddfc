"""One region's activity against the camera's noise (docs/noise.md): the estimator's noise floor,
its value above the floor with a verdict, and the signal quality, from a window of frames.

The composition :func:`region_noise` is what ``edgedsm analyze --json`` reports (``noise_floor``,
``above_noise``, ``signal``); the formulas are in :mod:`~edgedsm.estimators.noise_floor` and
:mod:`~edgedsm.estimators.signal_quality`. Pure: arrays in, a dataclass out.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from edgedsm.errors import EstimatorError
from edgedsm.estimators import noise, noise_floor, signal_quality
from edgedsm.estimators.noise import NoiseModel
from edgedsm.estimators.noise_floor import AboveNoise


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


def region_noise(frames: np.ndarray, estimate_map: np.ndarray, estimator: str, lag: int, *, q: float = 0.0,
                 model: NoiseModel | None = None, mask: np.ndarray | None = None,
                 bits: int | None = None) -> RegionNoise:
    """The noise summary of the (N, H, W) ``frames`` window whose ``estimator`` map ("s1", "s2"
    or "s3" at ``lag``) is ``estimate_map``, over the boolean ``mask`` (default: all pixels).
    ``model``: the camera's noise model; None estimates it from the frames
    (:func:`~edgedsm.estimators.noise.from_frames`), which fails on activity faster than a few
    frames: then ``model_error`` says so and only the light is judged."""
    stack = np.asarray(frames)
    if stack.ndim != 3:
        raise EstimatorError(f"frames must be a (N, H, W) stack, got shape {stack.shape}")
    if estimator not in ("s1", "s2", "s3"):
        raise EstimatorError(f"estimator must be s1, s2 or s3, got {estimator!r}")
    region = np.ones(stack.shape[1:], bool) if mask is None else np.asarray(mask, bool)
    top = full_scale(stack, bits)
    estimate = float(np.asarray(estimate_map, np.float64)[region].mean())
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
    means = stack[:, region].mean(axis=0, dtype=np.float64)
    above = _above(stack, estimator, lag, q, model, means, estimate, region, top)
    light = signal_quality.light_stats(stack, model, top, region)
    quality = signal_quality.signal_quality(light, above)
    return RegionNoise(estimator, estimate, above.floor, above.value, above.spread, above.verdict, quality.verdict,
                       quality.dark_fraction, quality.saturated_fraction, light.speckle_contrast,
                       {"source": model.source, "gain": model.gain, "dark_mean": model.dark_mean,
                        "dark_variance": model.dark_variance, "relative_error": model.relative_error})


def _above(stack: np.ndarray, estimator: str, lag: int, q: float, model: NoiseModel, means: np.ndarray,
           estimate: float, region: np.ndarray, top: float) -> AboveNoise:
    n = stack.shape[0]
    if estimator == "s1":
        return noise_floor.above_noise(estimate, noise_floor.s1_floor(model, means, n, lag, top=top))
    if estimator == "s2":
        return noise_floor.above_noise(estimate, noise_floor.s2_floor(model, means, n, lag, q=q, top=top))
    # S3 of the signal alone needs the region's S1 and its mean window variance (Eq. 3-4)
    from edgedsm.estimators import s1

    s1_value = float(s1(stack, lag)[region].mean())
    variance = float(stack[:, region].astype(np.float64).var(axis=0).mean())
    share = noise_floor.signal_share(model, means, variance, n, top=top)
    value = noise_floor.s3_signal(estimate, s1_value, noise_floor.s1_floor(model, means, n, lag, top=top), share)
    if not math.isfinite(value.value):
        raise EstimatorError("S3 above noise is not finite")
    return value
