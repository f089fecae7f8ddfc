"""Camera noise model: the temporal noise variance of a pixel as a function of its mean signal.

EMVA 1288 (release 4.0, §2 "linear camera model") writes a linear camera's temporal variance
in digital numbers (DN) as::

    σ²(μ) = K·(μ - μ_dark) + σ_d² + 1/12          (DN²; μ, μ_dark in DN)

with K the system gain (DN per electron: the shot noise of μ_e electrons is K²·μ_e = K·μ_e·K),
σ_d² the dark (read + thermal) noise in DN² and 1/12 DN² the quantization noise of rounding to
integers (a uniform error of one step; absent for float data). The 1/12 is Sheppard's
correction and holds for an analog σ above about 0.5 DN; below, the variance of rounded data
is smaller (0 for σ = 0), so integer frames use the exact mean over the position of the
signal within its grey step, :func:`rounded_variance`. The model assumes shot noise that is
Poisson in electrons (so linear in μ), noise independent from frame to frame and from pixel to
pixel, and no saturation or clipping at 0 (pixels that touch either are left out of
every fit). Three sources give K, σ_d² and μ_dark (docs/noise.md says when each is used):

* :func:`from_datasheet`: the camera's EMVA 1288 datasheet (K in DN/e⁻, σ_d in e⁻).
* :func:`photon_transfer`: a photon-transfer measurement, dark frames and frames of a static
  target. Each pixel's temporal variance is taken from frame differences, E[(I_t - I_{t+1})²]/2,
  EMVA 1288's difference of two frames (it removes the fixed pattern, which does not change
  between frames); K is the slope of σ² - σ²_dark against μ - μ_dark through the origin
  (EMVA 1288 §6.3), over pixels grouped by mean below 70 % of saturation. A static speckle
  target spreads the pixels' means over the range, so one exposure is enough.
* :func:`from_frames`: neither given; the measurement's own frames. Their structure function
  D(k) = E[(I_t - I_{t+k})²] = 2σ_n² + 2σ_s²(1 - ρ(k)) (as differential dynamic microscopy
  separates noise from dynamics) has a white, lag-independent part 2σ_n²: fitted per group of
  pixels with equal means, with ρ(k) = exp(-(k/τ)^p), p from 1/2 to 2 (p = 1 is the simulator's
  and the τc fit's model; real films also drift, p = 2, or relax over many times, p < 1: DDM
  fits the same stretched exponentials), and then σ_n² fitted against the groups' means as the
  line above. Differences need no window-mean
  correction. It cannot separate noise from activity faster than the frame rate (τc below about
  a frame: the signal is white too): such groups are left out, as are groups whose white part
  is as large as speckle's own fluctuation (MAX_WHITE_CONTRAST: a flat D(k) fits any τ), and
  with none left there is no estimate (:class:`~edgedsm.errors.EstimatorError`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from scipy.special import ndtr

from edgedsm.errors import EstimatorError
from edgedsm.estimators.ambient import mean_square_difference
from edgedsm.estimators.batch import check_frames

#: DN²: variance of the rounding error of a quantizer with a step of 1 DN (uniform on ±1/2).
QUANTIZATION_VARIANCE = 1.0 / 12.0
#: EMVA 1288 fits the photon-transfer slope below this fraction of saturation (nonlinearity).
PTC_MAX_FRACTION = 0.7
GROUPS = 16  # pixels are grouped by mean into this many equal-count groups
MIN_GROUP_PIXELS = 32
#: the white part is separable from the activity only where the signal stays correlated for
#: about a frame: groups whose fitted τ is below this many frames are left out
MIN_RESOLVED_TAU = 4.0
#: the least relative error from_frames states: its fit scatter alone (0.1-0.5 %) leaves out how
#: the separation depends on the activity's shape (3-14 % between stages of one glue recording)
FRAMES_MIN_ERROR = 0.05
MIN_GROUP_MEAN = 3.0  # DN: dimmer groups are left out of from_frames' fit (see there)
#: a white part whose σ is above this share of the group's mean is speckle that decorrelates
#: within a frame, not noise: temporally varying speckle has σ = μ (fully developed; Goodman,
#: Speckle Phenomena in Optics, §3.2) or μ/√M over M speckles per pixel, while shot noise of μ_e
#: electrons has σ/μ = 1/√μ_e, above 0.25 only below 16 electrons, a pixel too dark to time.
MAX_WHITE_CONTRAST = 0.25
#: the white part is an extrapolation of D(k) to k = 0, best made from the shortest lags
DEFAULT_LAGS = 6
_TAU_GRID = 0.25 * 2.0 ** (np.arange(0, 161) / 8.0)  # 0.25 ... 2^20·0.25 frames, 9 % steps
_STRETCH = (0.5, 0.75, 1.0, 1.5, 2.0)  # the exponents p of ρ(k) = exp(-(k/τ)^p)


_ROUNDING_TOP = 4.0  # DN: analog σ up to which rounding is tabulated; beyond, σ² + 1/12 within 1e-6


@lru_cache(maxsize=1)
def _rounding_table() -> tuple[np.ndarray, np.ndarray]:
    """Analog σ (DN) and E_x Var(round(x + n)), n ~ N(0, σ²), x uniform over a grey step."""
    sigma = np.linspace(0.0, _ROUNDING_TOP, 801)
    offset = (np.arange(256) + 0.5) / 256.0
    level = np.arange(-30, 31, dtype=np.float64)
    edge = (level[0] - 0.5 + np.arange(level.size + 1)) - offset[:, None]  # (X, J+1): level j is [j-½, j+½)
    variance = np.empty(sigma.size)
    # one σ at a time: a (X, J+1) slab stays in cache, and each edge's Φ serves the levels on
    # both sides of it (a (σ, X, J) array of both edges of each level took ten times as long,
    # at every daemon start)
    for i, s in enumerate(np.maximum(sigma, 1e-9)):
        prob = np.diff(ndtr(edge / s), axis=1)  # (X, J)
        mean = prob @ level
        variance[i] = (prob @ level**2 - mean**2).mean()
    return sigma, variance


def rounded_variance(analog_variance: np.ndarray | float) -> np.ndarray:
    """Temporal variance (DN²) of integer frames whose analog noise variance is given: σ² + 1/12
    for σ >= 4 DN, the exact mean over the signal's position within its grey step below."""
    analog = np.asarray(analog_variance, np.float64)
    sigma, table = _rounding_table()
    root = np.sqrt(analog)
    return np.where(root < _ROUNDING_TOP, np.interp(root, sigma, table), analog + QUANTIZATION_VARIANCE)


def analog_variance_of(rounded: np.ndarray | float) -> np.ndarray:
    """The inverse of :func:`rounded_variance` (DN² to DN²; 0 below the table's first value)."""
    measured = np.asarray(rounded, np.float64)
    sigma, table = _rounding_table()
    inside = np.interp(measured, table, sigma) ** 2
    return np.where(measured < table[-1], inside, measured - QUANTIZATION_VARIANCE)


@dataclass(frozen=True)
class NoiseModel:
    """σ²(μ) = K·max(μ - μ_dark, 0) + σ_d² (+ 1/12 if quantized), in DN².

    ``gain`` K (DN/e⁻), ``dark_mean`` μ_dark (DN), ``dark_variance`` σ_d² (DN², before
    quantization), ``quantized`` (integer frames), ``relative_error`` the 1-σ relative
    uncertainty of the modelled variance (0: exact), ``source`` where it came from.
    """

    gain: float
    dark_mean: float = 0.0
    dark_variance: float = 0.0
    quantized: bool = True
    relative_error: float = 0.0
    source: str = "datasheet"

    def __post_init__(self) -> None:
        for name in ("gain", "dark_mean", "dark_variance", "relative_error"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) \
                    or value < 0:
                raise EstimatorError(f"noise model: {name} must be a finite number >= 0, got {value!r}")
        if self.relative_error >= 1.0:
            raise EstimatorError(f"noise model: relative_error must be below 1, got {self.relative_error}")

    def analog_variance(self, mean: np.ndarray | float) -> np.ndarray:
        """Temporal variance before quantization, K·max(μ - μ_dark, 0) + σ_d² (DN²)."""
        mu = np.asarray(mean, np.float64)
        return self.gain * np.maximum(mu - self.dark_mean, 0.0) + self.dark_variance

    def variance(self, mean: np.ndarray | float) -> np.ndarray:
        """Temporal noise variance σ²(μ) of a pixel whose mean is ``mean`` (DN²); integer frames:
        :func:`rounded_variance` of the analog variance (σ² + 1/12 above σ = 4 DN)."""
        analog = self.analog_variance(mean)
        return rounded_variance(analog) if self.quantized else analog


def from_datasheet(gain: float, dark_noise_e: float, dark_mean: float = 0.0, quantized: bool = True,
                   relative_error: float = 0.05) -> NoiseModel:
    """The model from an EMVA 1288 datasheet: system gain K (DN/e⁻), dark noise σ_d (e⁻) and
    the dark offset μ_dark (DN); σ_d² in DN² is (K·σ_d)². ``relative_error`` defaults to 5 %,
    the spread EMVA 1288 datasheets allow between cameras of one model."""
    if not (isinstance(dark_noise_e, int | float) and math.isfinite(dark_noise_e) and dark_noise_e >= 0):
        raise EstimatorError(f"dark_noise_e must be a finite number >= 0, got {dark_noise_e!r}")
    return NoiseModel(gain=float(gain), dark_mean=float(dark_mean), dark_variance=(gain * dark_noise_e) ** 2,
                      quantized=quantized, relative_error=relative_error, source="datasheet")


def _stack(frames: np.ndarray, what: str, minimum: int) -> np.ndarray:
    stack = check_frames(frames)
    if stack.shape[0] < minimum:
        raise EstimatorError(f"{what}: need at least {minimum} frames, got {stack.shape[0]}")
    return stack


def _top(stack: np.ndarray, saturation: float | None) -> float:
    if saturation is not None:
        if not math.isfinite(saturation) or saturation <= 0:
            raise EstimatorError(f"saturation must be a finite grey level > 0, got {saturation!r}")
        return float(saturation)
    if np.issubdtype(stack.dtype, np.integer):
        return float(np.iinfo(stack.dtype).max)
    return math.inf


def _unclipped(stack: np.ndarray, top: float) -> np.ndarray:
    """Pixels (flat) that never touch 0 or saturation: their variance is not cut by clipping."""
    flat = stack.reshape(stack.shape[0], -1)
    return (flat.min(axis=0) > 0) & (flat.max(axis=0) < top)


def _groups(means: np.ndarray, keep: np.ndarray) -> list[np.ndarray]:
    """Indices of the kept pixels in up to GROUPS equal-count groups by mean."""
    index = np.flatnonzero(keep)
    if index.size < MIN_GROUP_PIXELS:
        raise EstimatorError(f"only {index.size} unclipped pixels (need {MIN_GROUP_PIXELS}): "
                             "too many pixels at 0 or at saturation")
    order = index[np.argsort(means[index], kind="stable")]
    count = max(1, min(GROUPS, index.size // MIN_GROUP_PIXELS))
    return np.array_split(order, count)


def photon_transfer(dark: np.ndarray, bright: np.ndarray, saturation: float | None = None) -> NoiseModel:
    """K, σ_d² and μ_dark from ``dark`` frames (no light) and ``bright`` frames of a static
    target (each (N >= 2, H, W), same camera settings), EMVA 1288 §6 (module docstring)."""
    dark_stack = _stack(dark, "dark frames", 2)
    stack = _stack(bright, "frames of a static target", 2)
    quantized = bool(np.issubdtype(stack.dtype, np.integer))
    analog = analog_variance_of if quantized else np.asarray
    dark_mean = float(dark_stack.mean(dtype=np.float64))
    dark_variance = float(analog(float(mean_square_difference(dark_stack, 1).mean()) / 2.0))
    top = _top(stack, saturation)
    means = stack.mean(axis=0, dtype=np.float64).reshape(-1)
    variances = mean_square_difference(stack, 1).reshape(-1) / 2.0
    keep = _unclipped(stack, top) & (means < PTC_MAX_FRACTION * top) & (means > dark_mean)
    groups = _groups(means, keep)
    x = np.array([means[g].mean() for g in groups]) - dark_mean
    y = analog(np.array([variances[g].mean() for g in groups])) - dark_variance
    if float((x * x).sum()) <= 0.0:
        raise EstimatorError("the static target is no brighter than the dark frames")
    gain = max(float((x * y).sum() / (x * x).sum()), 0.0)  # through the origin, EMVA 1288 §6.3
    spread = math.sqrt(float(((y - gain * x) ** 2).mean()))
    level = float((y + dark_variance).mean())
    return NoiseModel(gain=gain, dark_mean=dark_mean, dark_variance=dark_variance,
                      quantized=quantized, relative_error=min(spread / level / math.sqrt(len(groups)), 0.5),
                      source="photon_transfer")


def white_variance(structure: np.ndarray, lags: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """σ_n² (DN²) and τ (frames) of rows of structure functions D(k) (shape (G, L), at ``lags``).

    Least squares of D(k) = 2σ_n² + B·(1 - exp(-(k/τ)^p)) with σ_n², B >= 0: closed form in
    (σ_n², B) at each (τ, p) of a grid, the best kept (no refinement: σ_n² varies slowly with τ
    near the minimum).
    """
    d = np.asarray(structure, np.float64)
    k = np.asarray(lags, np.float64)
    scaled = k[None, None, :] / _TAU_GRID[None, :, None]
    rise = (1.0 - np.exp(-scaled ** np.array(_STRETCH)[:, None, None])).reshape(-1, k.size)  # (P·T, L)
    taus = np.tile(_TAU_GRID, len(_STRETCH))
    # every grid point at once: the least-squares solution of each (L, 2) basis [1, rise] is its
    # pseudo-inverse times D (SVD, the same cut-off as lstsq's; the bases at the shortest τ are
    # singular, rise ≈ 1 at every lag)
    basis = np.stack([np.ones_like(rise), rise], axis=2)  # (P·T, L, 2)
    white, slope = np.moveaxis(np.linalg.pinv(basis) @ d.T, 1, 0)  # each (P·T, G)
    # a bound active: the other parameter alone, by least squares
    flat = slope < 0
    white = np.where(flat, d.mean(axis=1)[None, :], white)
    slope = np.where(flat, 0.0, slope)
    through = white < 0
    slope = np.where(through, (rise @ d.T) / (rise * rise).sum(axis=1)[:, None], slope)
    white = np.where(through, 0.0, white)
    resid = ((d[None, :, :] - white[:, :, None] - slope[:, :, None] * rise[:, None, :]) ** 2).sum(axis=2)
    resid = np.where(np.isnan(resid), np.inf, resid)
    best = np.argmin(resid, axis=0)  # the first of equal minima, as a scan in grid order keeps
    columns = np.arange(d.shape[0])
    found = np.isfinite(resid[best, columns])
    return np.where(found, white[best, columns] / 2.0, 0.0), np.where(found, taus[best], 0.0)


def from_frames(frames: np.ndarray, max_lag: int = DEFAULT_LAGS, saturation: float | None = None,
                mask: np.ndarray | None = None) -> NoiseModel:
    """The model from the measurement's own frames (module docstring), over the pixels of the
    boolean (H, W) ``mask`` (default all); lags 1..``max_lag`` (at most N/4)."""
    stack = _stack(frames, "frames", 8)
    n = stack.shape[0]
    if isinstance(max_lag, bool) or not isinstance(max_lag, int) or max_lag < 2:
        raise EstimatorError(f"max_lag must be an integer >= 2, got {max_lag!r}")
    top_lag = min(max_lag, n // 4)
    if top_lag < 2:
        raise EstimatorError(f"{n} frames are too few to separate the noise (need at least 8)")
    lags = np.arange(1, top_lag + 1)
    quantized = bool(np.issubdtype(stack.dtype, np.integer))
    keep = _unclipped(stack, _top(stack, saturation))
    if mask is not None:
        region = np.asarray(mask)
        if region.dtype != np.bool_ or region.shape != stack.shape[1:]:
            raise EstimatorError(f"mask must be a boolean {stack.shape[1:]} array")
        keep &= region.reshape(-1)
    means = stack.mean(axis=0, dtype=np.float64).reshape(-1)
    groups = _groups(means, keep)
    structure = np.stack([mean_square_difference(stack, int(k)).reshape(-1) for k in lags])  # (L, P)
    pooled = np.array([structure[:, g].mean(axis=1) for g in groups])  # (G, L)
    noise, tau = white_variance(pooled, lags)
    group_means = np.array([means[g].mean() for g in groups])
    # dim groups: leaving out the pixels that touch 0 keeps those whose signal sits mid-step,
    # whose rounded variance is below the step-average the inversion assumes
    resolved = (tau >= MIN_RESOLVED_TAU) & (group_means >= MIN_GROUP_MEAN)
    resolved &= noise <= (MAX_WHITE_CONTRAST * group_means) ** 2  # (τ is arbitrary where D(k) is flat)
    if not resolved.any():
        raise EstimatorError("the frames cannot tell noise from activity (the activity decorrelates "
                             "within a few frames, or the frames are too dark): give the camera's noise "
                             "(datasheet or photon transfer)")
    x = group_means[resolved]
    y = analog_variance_of(noise[resolved]) if quantized else noise[resolved]
    gain, intercept = 0.0, -1.0
    if x.size >= 3 and float(np.ptp(x)) > 0.0:
        gain, intercept = (float(v) for v in np.polyfit(x, y, 1))
    if gain <= 0.0 or intercept < 0.0:
        # a dark offset cannot be told from a noisy intercept here: the line goes through the
        # origin (μ_dark = 0), which errs towards more noise at low means (a higher floor)
        intercept = 0.0 if float((x * x).sum()) > 0 and float((x * y).sum()) > 0 else float(y.mean())
        gain = float((x * y).sum() / (x * x).sum()) if intercept == 0.0 else 0.0
    dof = max(x.size - 2, 1)
    spread = math.sqrt(float(((y - gain * x - intercept) ** 2).sum()) / dof)
    level = float(y.mean())
    relative = min(spread / level / math.sqrt(x.size), 0.5) if level > 0 else 0.0
    return NoiseModel(gain=gain, dark_mean=0.0, dark_variance=intercept, quantized=quantized,
                      relative_error=max(relative, FRAMES_MIN_ERROR), source="frames")


def abs_correlation(rho: np.ndarray | float) -> np.ndarray:
    """corr(|X|, |Y|) of a centred bivariate normal with corr(X, Y) = ρ:
    ((2/π)(sqrt(1 - ρ²) + ρ·asin ρ) - 2/π)/(1 - 2/π), from E|X||Y| = (2/π)σ²(sqrt(1 - ρ²) + ρ·asin ρ)."""
    r = np.clip(np.asarray(rho, np.float64), -1.0, 1.0)
    return (2.0 / math.pi) * (np.sqrt(1.0 - r * r) + r * np.arcsin(r) - 1.0) / (1.0 - 2.0 / math.pi)


def independent_pixels(frames: np.ndarray, mask: np.ndarray | None = None, reach: int = 2) -> float:
    """How many independent pixels a region's mean of |ΔI| (S1, S2) averages over: P /
    Σ_offsets corr(|Δ_p|, |Δ_p+offset|), offsets up to ``reach`` px, from the spatial correlation
    ρ of the frame differences I_{t+1} - I_t (white noise of a monochrome sensor: P; a colour
    camera's interpolated channel: about P/2). Activity correlates neighbours too, so an active
    surface reads fewer: a wider spread, the safe side."""
    stack = _stack(frames, "frames", 2)
    if isinstance(reach, bool) or not isinstance(reach, int) or not 0 <= reach < min(stack.shape[1:]):
        raise EstimatorError(f"reach must be an integer in [0, {min(stack.shape[1:])}), got {reach!r}")
    region = np.ones(stack.shape[1:], bool) if mask is None else np.asarray(mask)
    if region.dtype != np.bool_ or region.shape != stack.shape[1:] or not region.any():
        raise EstimatorError(f"mask must be a non-empty boolean {stack.shape[1:]} array")
    diff = np.diff(stack.astype(np.float64), axis=0)
    diff -= diff.mean(axis=(1, 2), keepdims=True)  # a frame-wide change (exposure) is not noise
    variance = float((diff * diff).mean())
    if variance <= 0.0:
        return float(region.sum())
    height, width = stack.shape[1:]
    total = 0.0
    for dy in range(-reach, reach + 1):
        for dx in range(-reach, reach + 1):
            a = diff[:, max(dy, 0):height + min(dy, 0), max(dx, 0):width + min(dx, 0)]
            b = diff[:, max(-dy, 0):height + min(-dy, 0), max(-dx, 0):width + min(-dx, 0)]
            total += float(abs_correlation((a * b).mean() / variance))
    return float(region.sum()) / max(total, 1.0)
