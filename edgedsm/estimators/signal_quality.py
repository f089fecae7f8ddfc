"""Signal quality of a region: is there light, unclipped, in speckle, with activity above noise?

Verdicts, first match wins (docs/noise.md justifies the bounds; none is tuned to a recording):

* ``saturated``: more than SATURATED_MAX of the window's samples (pixels × frames) are at full
  scale: their differences are clipped, so every estimator reads low by about that share. (Not
  the share of pixels that reach full scale once: over a window of a fast film most bright
  speckles do, with a negligible effect on the maps.)
* ``dark``: more than DARK_MAX of the pixels are dark, i.e. their mean is less than DARK_SNR
  noise σ above the dark level (a signal within 3σ of no light carries no speckle to time).
* ``not_speckle``: the frame's spatial speckle contrast (local mean removed, the noise's
  variance taken out) is below MIN_CONTRAST: a pixel integrating M speckles has contrast about
  1/sqrt(M) (Goodman, Speckle Phenomena in Optics, §4.6), so 0.1 is ~100 speckles per pixel,
  i.e. speckle a tenth of a pixel across: out of focus or the aperture far too wide.
* ``low``: the activity is within its noise (an :class:`~edgedsm.estimators.noise_floor.AboveNoise`
  verdict ``low``); ``ok`` otherwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter

from edgedsm.errors import EstimatorError
from edgedsm.estimators.noise import NoiseModel
from edgedsm.estimators.noise_floor import AboveNoise

SATURATED_MAX = 0.05  # fraction of samples: clipped differences bias S1 by about this fraction
DARK_SNR = 3.0  # noise σ above the dark level a pixel's mean must reach to count as lit
DARK_MAX = 0.5  # fraction of pixels: most of the region unlit
MIN_CONTRAST = 0.1  # spatial speckle contrast (signal only)
LOCAL_MEAN = 9  # px: box removing the illumination profile, several speckles wide at speckle sizes <= 3 px
OK, LOW, DARK, SATURATED, NOT_SPECKLE = "ok", "low", "dark", "saturated", "not_speckle"


@dataclass(frozen=True)
class LightStats:
    """A region's light over a window: mean (DN), the dark pixels' and the saturated samples'
    fractions, and the spatial speckle contrast of one frame (dimensionless, noise removed)."""

    mean: float
    dark_fraction: float
    saturated_fraction: float
    speckle_contrast: float


@dataclass(frozen=True)
class SignalQuality:
    verdict: str
    dark_fraction: float
    saturated_fraction: float


def light_stats(frames: np.ndarray, model: NoiseModel, top: float, mask: np.ndarray | None = None) -> LightStats:
    """LightStats of the (N, H, W) window over the boolean (H, W) ``mask`` (default all);
    ``top``: the camera's full scale (DN). The saturated fraction is of the samples (pixels ×
    frames), the dark one of the pixels; the contrast is that of the last frame."""
    stack = np.asarray(frames)
    if stack.ndim != 3 or stack.shape[0] < 1:
        raise EstimatorError(f"frames must be a (N, H, W) stack, got shape {stack.shape}")
    if not math.isfinite(top) or top <= 0:
        raise EstimatorError(f"top must be a finite grey level > 0, got {top!r}")
    region = np.ones(stack.shape[1:], bool) if mask is None else np.asarray(mask)
    if region.dtype != np.bool_ or region.shape != stack.shape[1:] or not region.any():
        raise EstimatorError(f"mask must be a non-empty boolean {stack.shape[1:]} array")
    means = stack.mean(axis=0, dtype=np.float64)
    saturated = (stack[:, region] >= top)
    sigma = np.sqrt(model.variance(means))
    dark = (means - model.dark_mean < DARK_SNR * sigma)[region]
    frame = stack[-1].astype(np.float64)
    local = uniform_filter(frame, LOCAL_MEAN, mode="reflect")
    level = float(local[region].mean())
    fine = float(((frame - local)[region] ** 2).mean()) - float(model.variance(means)[region].mean())
    contrast = math.sqrt(max(fine, 0.0)) / level if level > 0 else 0.0
    return LightStats(float(means[region].mean()), float(dark.mean()), float(saturated.mean()), contrast)


def signal_quality(light: LightStats, activity: AboveNoise | None = None) -> SignalQuality:
    """The region's verdict (module docstring) with its dark and saturated fractions."""
    for name in ("dark_fraction", "saturated_fraction"):
        value = getattr(light, name)
        if not 0.0 <= value <= 1.0:
            raise EstimatorError(f"{name} must be in [0, 1], got {value!r}")
    if light.saturated_fraction > SATURATED_MAX:
        verdict = SATURATED
    elif light.dark_fraction > DARK_MAX:
        verdict = DARK
    elif light.speckle_contrast < MIN_CONTRAST:
        verdict = NOT_SPECKLE
    elif activity is not None and activity.verdict != OK:
        verdict = LOW
    else:
        verdict = OK
    return SignalQuality(verdict, light.dark_fraction, light.saturated_fraction)
