"""Noise floors of the activity estimators and the activity above them (docs/noise.md).

A region's floor is what a *static* surface with the same pixel means and the same camera
noise (:class:`~edgedsm.estimators.noise.NoiseModel`) would give; its spread is the 1-σ
scatter of the region's estimate around the floor (finite window and region, plus the noise
model's own uncertainty). Inputs are the region's per-pixel temporal means μ_p (DN) over the
window of N frames; the lag m is in frames.

* S1 (Eq. 1, DN): floor = mean_p E|n_t - n_{t+m}|, two independent noise samples of one pixel:
  2σ/√π for Gaussian noise of variance σ²; for integer frames the rounding and the clipping at
  0 and at saturation are summed exactly (:func:`static_pair_moments`), which matters below
  σ ≈ 1 DN and for dim pixels. Above-noise S1 = S1 - floor.
* S2 (Eq. 2, dimensionless): floor = mean_p E[|Δn|/(I_i + I_{i+m} + q)], summed the same way
  (float frames: E|Δn|·E[1/x], x = I_i + I_{i+m} + q, Δn and x independent for Gaussian noise,
  E[1/x] to second order); above-noise S2 = S2 - floor.
* S3 (Eq. 3-4): noise adds in quadrature to the differences (E[Δ²] = E[Δs²] + 2σ_n²; with the
  Gaussian shape E|Δ| ∝ sqrt(E[Δ²])) and to the variance, so S3 of the signal alone is
  S3·sqrt(1 - f1²/S1²)/sqrt(1 - (1 - 1/N)·σ̄_n²/σ̄²) (f1 the S1 floor, σ̄² the region's mean window
  variance). Defined only where S1 and the variance are above noise (else 0, ``low``).
* Fujii (BSLTL, 0..200): 200 × S2's floor at q = eps. IM (DN²): E[Δ²] of a static pair. GD (DN):
  E|Δ| as S1's (every pair of frames is two independent noise samples), with a U-statistic's
  spread. Above-noise values are the estimate less the floor, as for S1 and S2.
* Temporal contrast σ/⟨I⟩: floor E[σ̂]/μ per pixel (σ̂ over N frames of noise σ_n); noise adds in quadrature to
  the variance, so the signal's contrast is the contrast times sqrt(signal share) (below).
* τc: white noise lowers the fitted amplitude A (the signal's share of the variance) and not τ;
  the above-noise measure is that share, 1 - (1 - 1/N)·σ̄_n²/σ̄², and τc stands for the signal
  only where it is above noise.

Verdict ``low``: the above-noise value is below LOW_SPREADS spreads (one-sided, 0.13 % of pure
noise windows read ``ok`` for Gaussian spreads).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr

from edgedsm.errors import EstimatorError
from edgedsm.estimators.correlation_time import BELOW
from edgedsm.estimators.correlation_time import NO_SIGNAL as TAU_NO_SIGNAL
from edgedsm.estimators.descriptors import BSLTL_EPS
from edgedsm.estimators.noise import QUANTIZATION_VARIANCE, NoiseModel, abs_correlation

LOW_SPREADS = 3.0
#: corr(|a - b|, |b - c|) for independent Gaussian a, b, c: the two differences have correlation -1/2
OVERLAP_CORRELATION = float(abs_correlation(-0.5))
REPRESENTATIVES = 512  # pixel means a region's floor is computed from
#: DN: analog σ below which rounding is summed exactly; beyond, the Gaussian forms for integers
#: agree with the exact sum to 0.1 % (checked in the tests)
EXACT_SIGMA = 4.0
OK, LOW, NO_SIGNAL = "ok", "low", "no_signal"
#: corr(Δ1², Δ2²) of two Gaussian differences with corr(Δ1, Δ2) = -1/2: ρ² (Isserlis)
SQUARED_OVERLAP_CORRELATION = 0.25
#: Var(E|Z - Z'| given Z) for independent standard normal Z, Z' (E|z - Z'| = 2φ(z) + z(2Φ(z) - 1)),
#: by quadrature; checked in the tests
GD_ZETA1 = 0.16275157944175422


@dataclass(frozen=True)
class Floor:
    """An estimator's noise floor and its 1-σ spread, in the estimator's units."""

    value: float
    spread: float


@dataclass(frozen=True)
class AboveNoise:
    """The activity above the noise floor (estimator's units), its spread, the floor, and the
    verdict: ``ok``, ``low`` (within LOW_SPREADS spreads of zero) or ``no_signal``."""

    value: float
    spread: float
    floor: float
    verdict: str


def _means(means: np.ndarray) -> np.ndarray:
    mu = np.asarray(means, np.float64).reshape(-1)
    if mu.size == 0:
        raise EstimatorError("a region needs at least one pixel")
    if not np.isfinite(mu).all() or (mu < 0).any():
        raise EstimatorError("pixel means must be finite and >= 0")
    return mu


def _window(n: int, lag: int) -> None:
    if isinstance(n, bool) or isinstance(lag, bool) or not isinstance(n, int | np.integer) \
            or not isinstance(lag, int | np.integer) or not 1 <= lag <= n - 1:
        raise EstimatorError(f"need integers 1 <= lag <= N-1, got N={n!r}, lag={lag!r}")


def _representatives(mu: np.ndarray) -> np.ndarray:
    """At most REPRESENTATIVES pixel means standing for the region, each for an equal share
    (evenly spaced order statistics): the floors are means over pixels, and this bounds their cost."""
    if mu.size <= REPRESENTATIVES:
        return mu
    ordered = np.sort(mu)
    return ordered[np.linspace(0, mu.size - 1, REPRESENTATIVES).round().astype(np.int64)]


def _gaussian_moments(mu: np.ndarray, variance: np.ndarray, q: float,
                      quantized: bool = False) -> tuple[np.ndarray, ...]:
    """E|Δ|, E[Δ²], E[r], E[r²] for Gaussian noise of ``variance`` σ²: 2σ/√π, 2σ², and with
    x = 2μ + q, E[r] ≈ E|Δ|·(1 + 2σ²/x²)/x (Δ and the sum independent, E[1/x] to second
    order), E[r²] ≈ 2σ²/x². ``quantized``: σ² is the analog variance and Δ an integer; then
    E[Δ²] gains Sheppard's 2/12 but E|Δ| does not (summing |k| over the integers takes
    f(0)/6 off E|X|, Euler-Maclaurin at the kink of |x|, and Sheppard's 1/6 adds it back to
    first order in 1/σ²)."""
    mean_abs = 2.0 * np.sqrt(variance) / math.sqrt(math.pi)
    if quantized:
        variance = variance + QUANTIZATION_VARIANCE
    level = 2.0 * mu + q
    lit = level > 0
    safe = np.where(lit, level, 1.0)
    ratio = np.where(lit, np.minimum(mean_abs / safe * (1.0 + 2.0 * variance / safe**2), 1.0), 0.0)
    ratio_sq = np.where(lit, np.minimum(2.0 * variance / safe**2, 1.0), 0.0)
    return mean_abs, 2.0 * variance, ratio, ratio_sq


def _rounded_moments(mu: np.ndarray, sigma: np.ndarray, q: float, top: float) -> tuple[np.ndarray, ...]:
    """The same for round(ν + n), n ~ N(0, σ²), clipped to [0, top], summed exactly over the
    levels within 6σ + 2 of ν, where ν is the analog mean whose rounded frames average μ
    (:func:`_analog_means`).

    For the levels' values v_k (non-decreasing in k) and probabilities p_k: E|Δ| =
    2 Σ_k P(I <= v_k)·P(I > v_k)·(v_{k+1} - v_k) (Gini's mean difference of a distribution on a
    lattice: non-negative terms only) and E[Δ²] = 2·Σp·Σ p_k (v_k - v̄)², both in one pass over
    the levels; the ratio's moments need the pairs, Σ_jk p_j p_k r(v_j, v_k) as a product of a
    matrix that depends only on the pixel's base level (computed once per base) with p."""
    mu = _analog_means(mu, sigma, top)
    out = [np.empty(mu.size) for _ in range(4)]
    reach = math.ceil(6.0 * float(sigma.max(initial=0.0))) + 2
    offsets = np.arange(-reach, reach + 1, dtype=np.float64)
    chunk = max(1, (1 << 22) // offsets.size**2)
    for start in range(0, mu.size, chunk):
        part = slice(start, start + chunk)
        m, s = mu[part, None], np.maximum(sigma[part, None], 1e-9)
        base = np.floor(m)
        prob = ndtr((base + offsets + 0.5 - m) / s) - ndtr((base + offsets - 0.5 - m) / s)  # (P, J)
        centred = np.clip(base + offsets, 0.0, top) - base  # small numbers: no cancellation below
        below = np.cumsum(prob, axis=1)[:, :-1]
        above = np.cumsum(prob[:, ::-1], axis=1)[:, ::-1][:, 1:]
        out[0][part] = 2.0 * (below * above * np.diff(centred, axis=1)).sum(axis=1)
        mass = prob.sum(axis=1)
        mean = (prob * centred).sum(axis=1) / np.where(mass > 0, mass, 1.0)
        out[1][part] = 2.0 * mass * (prob * (centred - mean[:, None]) ** 2).sum(axis=1)
        bases, which = np.unique(base[:, 0], return_inverse=True)
        values = np.clip(bases[:, None] + offsets, 0.0, top)  # (B, J)
        total = values[:, :, None] + values[:, None, :] + q
        ratio = np.divide(np.abs(values[:, :, None] - values[:, None, :]), total,
                          out=np.zeros_like(total), where=total > 0)[which]  # (P, J, J)
        column = prob[:, :, None]
        out[2][part] = (prob * np.matmul(ratio, column)[:, :, 0]).sum(axis=1)
        out[3][part] = (prob * np.matmul(ratio * ratio, column)[:, :, 0]).sum(axis=1)
    return tuple(out)


def _analog_means(mu: np.ndarray, sigma: np.ndarray, top: float) -> np.ndarray:
    """:func:`_invert_means`, remembered for the last few inputs: S1's, S2's and S3's floors of one
    region (and the daemon's judges) ask for the same pixel means and noise in turn."""
    key = (mu.tobytes(), sigma.tobytes(), float(top))
    found = _ANALOG_MEMO.get(key)
    if found is None:
        found = _invert_means(mu, sigma, top)
        found.setflags(write=False)
        if len(_ANALOG_MEMO) >= ANALOG_MEMO_SIZE:
            _ANALOG_MEMO.pop(next(iter(_ANALOG_MEMO)))
        _ANALOG_MEMO[key] = found
    return found


ANALOG_MEMO_SIZE = 8
INVERSION_POINTS = 33
_ANALOG_MEMO: dict[tuple[bytes, bytes, float], np.ndarray] = {}


def _invert_means(mu: np.ndarray, sigma: np.ndarray, top: float) -> np.ndarray:
    """The analog means ν (DN) whose rounded, clipped frames have the measured means μ.

    E[clip(round(ν + n), 0, top)] is a smooth staircase in ν (steps of width ~σ at the
    half-steps), bent flat near 0 and full scale: a rounded mean of 3.00 with σ = 0.1 DN says ν
    is well inside the step, where the frames never change, 3.40 that it is near 3.5, where they
    flip often, and 1.0 with σ = 1.6 DN that ν is below 1 (the clipped negatives raised the
    mean). Inverted per pixel on a grid of ν over μ ± (1.5 + 6σ), then on a grid across the two
    points that bracket it (INVERSION_POINTS each: a resolution of (1.5 + 6σ)/480 DN), linearly
    between the last two; ν = μ where σ >= 1 DN and the
    pixel is more than 1.5 + 6σ from both ends (the staircase is a straight line there within
    1e-4 DN)."""
    out = mu.copy()
    span = 1.5 + 6.0 * sigma
    invert = np.flatnonzero((sigma < 1.0) | (mu < span) | (mu > top - span))
    steps = np.linspace(0.0, 1.0, INVERSION_POINTS)[None, :]
    for start in range(0, invert.size, 32):  # 32 pixels at a time: (32, V, J) temporaries
        index = invert[start:start + 32]
        m, s, half = mu[index, None], np.maximum(sigma[index, None], 1e-9), span[index, None]
        value, rows = mu[index], np.arange(index.size)
        reach = math.ceil(float((half + 6.0 * s).max())) + 2
        levels = np.floor(m) + np.arange(-reach, reach + 1.0)[None, :]  # (P, J)
        clipped = np.clip(levels, 0.0, top)
        # E[clip(round(ν + n))] = v_first + Σ_k (v_{k+1} - v_k)·P(ν + n > k + 1/2): one Φ per
        # edge between two levels, not two per level
        rise = np.diff(clipped, axis=1)[:, None, :]  # (P, 1, J - 1)
        edges = (levels[:, :-1] + 0.5)[:, None, :]
        low, high = m - half, m + half
        # a coarse grid of ν brackets the solution, a fine one across the bracket finds it
        for _ in range(2):
            grid = low + (high - low) * steps  # candidate ν, (P, V)
            expected = clipped[:, :1] + (rise * ndtr((grid[:, :, None] - edges) / s[:, :, None])).sum(axis=2)
            expected += 1e-9 * np.arange(grid.shape[1])[None, :]  # strictly increasing for the inversion
            above = np.clip((expected < value[:, None]).sum(axis=1), 1, grid.shape[1] - 1)
            low, high = grid[rows, above - 1][:, None], grid[rows, above][:, None]
        below_e, above_e = expected[rows, above - 1], expected[rows, above]
        share = np.clip((value - below_e) / (above_e - below_e), 0.0, 1.0)
        out[index] = low[:, 0] + share * (high[:, 0] - low[:, 0])
    return out


def static_pair_moments(model: NoiseModel, means: np.ndarray, q: float = 0.0,
                        top: float = math.inf) -> tuple[np.ndarray, ...]:
    """For a static pixel of mean μ (DN): E|Δ|, E[Δ²], E[r], E[r²] of one pair of its frames,
    Δ = I_i - I_{i+m}, r = |Δ|/(I_i + I_{i+m} + q) (0 where the sum is 0).

    Integer frames with analog σ < EXACT_SIGMA: rounding and clipping summed exactly
    (:func:`_rounded_moments`); wider noise: the Gaussian forms for integers (clipping not
    modelled there). Float frames: Gaussian forms (:func:`_gaussian_moments`).
    """
    mu = np.asarray(means, np.float64).reshape(-1)
    analog = model.analog_variance(mu)
    if not model.quantized:
        return _gaussian_moments(mu, analog, q)
    result = [np.array(part, np.float64) for part in _gaussian_moments(mu, analog, q, quantized=True)]
    sigma = np.sqrt(analog)
    exact = sigma < EXACT_SIGMA
    if exact.any():
        for part, value in zip(result, _rounded(mu[exact], sigma[exact], float(q), float(top)), strict=True):
            part[exact] = value
    return tuple(result)


def _rounded(mu: np.ndarray, sigma: np.ndarray, q: float, top: float) -> tuple[np.ndarray, ...]:
    """:func:`_rounded_moments`, remembered for the last few inputs (S1's and S3's floors of one
    region ask for the same; so do the daemon's judges in turn)."""
    key = (mu.tobytes(), sigma.tobytes(), q, top)
    found = _ROUNDED_MEMO.get(key)
    if found is None:
        found = _rounded_moments(mu, sigma, q, top)
        for part in found:
            part.setflags(write=False)
        if len(_ROUNDED_MEMO) >= ANALOG_MEMO_SIZE:
            _ROUNDED_MEMO.pop(next(iter(_ROUNDED_MEMO)))
        _ROUNDED_MEMO[key] = found
    return found


_ROUNDED_MEMO: dict[tuple[bytes, bytes, float, float], tuple[np.ndarray, ...]] = {}


def mean_abs_difference(model: NoiseModel, means: np.ndarray | float) -> np.ndarray:
    """E|n_t - n_{t+m}| (DN) of a static pixel with mean μ: its noise floor for S1, per pixel."""
    return static_pair_moments(model, np.asarray(means, np.float64))[0].reshape(np.shape(means))


def _sampling(per_pixel_var: np.ndarray, n: int, lag: int, pixels: float) -> float:
    """1-σ of a region mean of |Δ| over N - m pairs per pixel and ``pixels`` independent pixels."""
    pairs = n - lag
    overlap = max(n - 2 * lag, 0)  # pairs sharing a frame with the pair m later
    factor = (pairs + 2.0 * OVERLAP_CORRELATION * overlap) / pairs**2
    return math.sqrt(max(float(per_pixel_var.mean()), 0.0) * factor / pixels)


def _pixels(mu: np.ndarray, independent_pixels: float | None) -> float:
    if independent_pixels is None:
        return float(mu.size)
    if not math.isfinite(independent_pixels) or not 0 < independent_pixels <= mu.size:
        raise EstimatorError(f"independent_pixels must be in (0, {mu.size}], got {independent_pixels!r}")
    return float(independent_pixels)


def _floor(model: NoiseModel, means: np.ndarray, n: int, lag: int, which: int, q: float, top: float,
           independent_pixels: float | None) -> Floor:
    mu = _means(means)
    _window(n, lag)
    if not math.isfinite(q) or q < 0:
        raise EstimatorError(f"q must be a finite number >= 0, got {q!r}")
    if not top > 0:
        raise EstimatorError(f"top must be a grey level > 0, got {top!r}")
    return _floor_of(static_pair_moments(model, _representatives(mu), q, top), which, model, mu, n, lag,
                     independent_pixels)


def _floor_of(moments: tuple[np.ndarray, ...], which: int, model: NoiseModel, mu: np.ndarray, n: int, lag: int,
              independent_pixels: float | None) -> Floor:
    first, second = moments[which], moments[which + 1]
    value = float(first.mean())
    sampling = _sampling(second - first**2, n, lag, _pixels(mu, independent_pixels))
    return Floor(value, math.hypot(sampling, value * model.relative_error / 2.0))


def s1_floor_and_static_variance(model: NoiseModel, means: np.ndarray, n: int, lag: int, top: float = math.inf,
                                 independent_pixels: float | None = None) -> tuple[Floor, float]:
    """:func:`s1_floor` and :func:`static_variance` at once (S3's above-noise needs both; they
    share the static pair moments, the costly part)."""
    mu = _means(means)
    _window(n, lag)
    if not top > 0:
        raise EstimatorError(f"top must be a grey level > 0, got {top!r}")
    moments = static_pair_moments(model, _representatives(mu), 0.0, top)
    return _floor_of(moments, 0, model, mu, n, lag, independent_pixels), float(moments[1].mean()) / 2.0


def s1_floor(model: NoiseModel, means: np.ndarray, n: int, lag: int, top: float = math.inf,
             independent_pixels: float | None = None) -> Floor:
    """S1's floor (DN) for a region of pixel means ``means`` (N frames, lag m, saturation at
    ``top`` DN). Noise is taken as independent between pixels unless ``independent_pixels``
    says fewer (colour cameras interpolate neighbours: :func:`~edgedsm.estimators.noise.independent_pixels`)."""
    return _floor(model, means, n, lag, 0, 0.0, top, independent_pixels)


def s2_floor(model: NoiseModel, means: np.ndarray, n: int, lag: int, q: float = 0.0, top: float = math.inf,
             independent_pixels: float | None = None) -> Floor:
    """S2's floor (dimensionless) for a region of pixel means ``means``, S2's offset q >= 0."""
    return _floor(model, means, n, lag, 2, q, top, independent_pixels)


def fujii_floor(model: NoiseModel, means: np.ndarray, n: int, lag: int, top: float = math.inf,
                independent_pixels: float | None = None) -> Floor:
    """Fujii's floor (0..200): 200 × S2's at BSLTL's q = eps, which Fujii is
    (:func:`edgedsm.estimators.descriptors.fujii`)."""
    floor = s2_floor(model, means, n, lag, q=BSLTL_EPS, top=top, independent_pixels=independent_pixels)
    return Floor(200.0 * floor.value, 200.0 * floor.spread)


def im_floor(model: NoiseModel, means: np.ndarray, n: int, lag: int, top: float = math.inf,
             independent_pixels: float | None = None) -> Floor:
    """The inertia moment's floor (DN²), mean (I_k - I_{k+m})² of a static pixel: E[Δ²] of
    :func:`static_pair_moments` (2σ² + Sheppard's 2/12 for integers). Spread: Δ² of Gaussian
    noise has variance 2·E[Δ²]², and squares of two pairs sharing a frame (correlation -1/2)
    correlate by 1/4; the model's relative error enters whole (IM goes as σ², not σ)."""
    mu = _means(means)
    _window(n, lag)
    if not top > 0:
        raise EstimatorError(f"top must be a grey level > 0, got {top!r}")
    second = static_pair_moments(model, _representatives(mu), 0.0, top)[1]
    value = float(second.mean())
    pairs, overlap = n - lag, max(n - 2 * lag, 0)
    factor = (pairs + 2.0 * SQUARED_OVERLAP_CORRELATION * overlap) / pairs**2
    sampling = math.sqrt(2.0 * float((second**2).mean()) * factor / _pixels(mu, independent_pixels))
    return Floor(value, math.hypot(sampling, value * model.relative_error))


def gd_floor(model: NoiseModel, means: np.ndarray, n: int, top: float = math.inf,
             independent_pixels: float | None = None) -> Floor:
    """The generalized differences' floor (DN), Σ_{i<j} |I_i - I_j| / C(N, 2) of a static pixel:
    every pair is two independent noise samples, so E|Δ| as S1's. Spread: GD is a U-statistic
    (Hoeffding, Ann. Math. Stat. 19, 1948), Var = (4(N-2)ζ1 + 2ζ2)/(N(N-1)) with ζ2 = Var|Δ| and
    ζ1 = Var_x E|x - Y| = GD_ZETA1·σ² for Gaussian noise."""
    mu = _means(means)
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 2:
        raise EstimatorError(f"N must be an integer >= 2, got {n!r}")
    if not top > 0:
        raise EstimatorError(f"top must be a grey level > 0, got {top!r}")
    first, second = static_pair_moments(model, _representatives(mu), 0.0, top)[:2]
    value = float(first.mean())
    per_pixel = (4.0 * (n - 2) * GD_ZETA1 * second / 2.0 + 2.0 * (second - first**2)) / (n * (n - 1))
    sampling = math.sqrt(max(float(per_pixel.mean()), 0.0) / _pixels(mu, independent_pixels))
    return Floor(value, math.hypot(sampling, value * model.relative_error / 2.0))


def contrast_floor(model: NoiseModel, means: np.ndarray, n: int, top: float = math.inf,
                   independent_pixels: float | None = None) -> Floor:
    """The temporal contrast's floor (:func:`contrast_floor_and_static_variance`)."""
    return contrast_floor_and_static_variance(model, means, n, top, independent_pixels)[0]


def contrast_floor_and_static_variance(model: NoiseModel, means: np.ndarray, n: int, top: float = math.inf,
                                       independent_pixels: float | None = None) -> tuple[Floor, float]:
    """The temporal contrast's floor (dimensionless): E[σ̂]/μ of a static pixel, σ̂ the population
    standard deviation of BSLTL's ``stdcont.m`` over N frames of Gaussian noise of variance σ_n²:
    E[σ̂] = sqrt(2/N)·Γ(N/2)/Γ((N-1)/2)·σ_n (the chi distribution's mean; sqrt(1 - 1/N)·σ_n would
    read a spread too high over a region), σ_n² = E[Δ²]/2 of :func:`static_pair_moments`
    (rounding and clipping included); 0 where μ = 0, as the map. Spread: σ̂ of white noise over N
    frames scatters by 1/sqrt(2(N - 1)) relative; the model's relative error enters halved. With it
    :func:`static_variance` (the contrast above the noise needs both; they share the static pair
    moments, the costly part)."""
    mu = _means(means)
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 2:
        raise EstimatorError(f"N must be an integer >= 2, got {n!r}")
    if not top > 0:
        raise EstimatorError(f"top must be a grey level > 0, got {top!r}")
    levels = _representatives(mu)
    chi_mean = math.sqrt(2.0 / n) * math.exp(math.lgamma(n / 2.0) - math.lgamma((n - 1) / 2.0))
    variance = static_pair_moments(model, levels, 0.0, top)[1] / 2.0
    sigma = np.sqrt(variance)
    lit = levels > 0
    per_pixel = np.zeros(levels.shape, np.float64)
    per_pixel[lit] = chi_mean * sigma[lit] / levels[lit]
    value = float(per_pixel.mean())
    sampling = math.sqrt(float((per_pixel**2).mean()) / (2.0 * (n - 1)) / _pixels(mu, independent_pixels))
    return Floor(value, math.hypot(sampling, value * model.relative_error / 2.0)), float(variance.mean())


def contrast_signal(contrast: float, floor: Floor, share: AboveNoise) -> AboveNoise:
    """The temporal contrast of the signal alone: noise adds in quadrature to the variance, so
    σ_s/⟨I⟩ = (σ/⟨I⟩)·sqrt(share) with the signal share of :func:`signal_share` (the region's
    noise share taken as every pixel's, as for S3); 0 and ``low`` where the share is within the
    noise (the spread: what one spread of share would give), ``no_signal`` where σ̄² = 0."""
    if not math.isfinite(contrast) or contrast < 0:
        raise EstimatorError(f"contrast must be finite and >= 0, got {contrast!r}")
    if share.verdict == NO_SIGNAL:
        return AboveNoise(0.0, 0.0, floor.value, NO_SIGNAL)
    if share.verdict == LOW or share.value <= 0.0:
        return AboveNoise(0.0, contrast * math.sqrt(max(share.spread, 0.0)), floor.value, LOW)
    value = contrast * math.sqrt(share.value)
    return AboveNoise(value, value * share.spread / (2.0 * share.value), floor.value, OK)


def above_noise(estimate: float, floor: Floor) -> AboveNoise:
    """A difference estimator's (S1, S2) region value above its floor, with the verdict."""
    if not math.isfinite(estimate):
        raise EstimatorError(f"estimate must be finite, got {estimate!r}")
    value = float(estimate) - floor.value
    verdict = LOW if value < LOW_SPREADS * floor.spread else OK
    return AboveNoise(value, floor.spread, floor.value, verdict)


def static_variance(model: NoiseModel, means: np.ndarray, top: float = math.inf) -> float:
    """σ̄_n² (DN²): a static pixel's temporal variance, E[Δ²]/2 of :func:`static_pair_moments`
    (rounding and clipping included), averaged over the pixel means ``means``."""
    mu = _means(means)
    if not top > 0:
        raise EstimatorError(f"top must be a grey level > 0, got {top!r}")
    return float(static_pair_moments(model, _representatives(mu), 0.0, top)[1].mean()) / 2.0


def signal_share(model: NoiseModel, means: np.ndarray, variance: float, n: int, top: float = math.inf,
                 independent_pixels: float | None = None, noise_variance: float | None = None) -> AboveNoise:
    """The signal's share of the region's temporal variance (τc's above-noise measure): 1 -
    (1 - 1/N)·σ̄_n²/σ̄², with ``variance`` σ̄² the region's mean window variance (Eq. 4's σ²,
    DN²) and σ̄_n² a static pixel's (:func:`static_variance` over the pixel means, or
    ``noise_variance`` when already known); ``no_signal`` where σ̄² = 0."""
    mu = _means(means)
    if not math.isfinite(variance) or variance < 0:
        raise EstimatorError(f"variance must be finite and >= 0, got {variance!r}")
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 2:
        raise EstimatorError(f"N must be an integer >= 2, got {n!r}")
    static = static_variance(model, mu, top) if noise_variance is None else float(noise_variance)
    if not math.isfinite(static) or static < 0:
        raise EstimatorError(f"noise_variance must be finite and >= 0, got {noise_variance!r}")
    noise = (1.0 - 1.0 / n) * static
    if variance <= 0.0:
        return AboveNoise(0.0, 0.0, 0.0, NO_SIGNAL)
    ratio = noise / variance
    # σ̂² of white noise over N frames scatters by sqrt(2/N) relative, pixel means by 1/sqrt(P)
    relative = math.hypot(math.sqrt(2.0 / (n * _pixels(mu, independent_pixels))), model.relative_error)
    spread = ratio * relative
    value = 1.0 - ratio
    return AboveNoise(value, spread, ratio, LOW if value < LOW_SPREADS * spread else OK)


def s3_signal(s3: float, s1: float, s1_noise: Floor, share: AboveNoise) -> AboveNoise:
    """S3 of the signal alone (module docstring) from the region's S3 and S1, S1's floor and the
    signal share (:func:`signal_share`); 0 and ``low`` where either is within the noise. The
    floor reported is S3's value for the noise alone, 2/√π (Gaussian noise, lag-independent)."""
    for name, value in (("s3", s3), ("s1", s1)):
        if not math.isfinite(value) or value < 0:
            raise EstimatorError(f"{name} must be finite and >= 0, got {value!r}")
    decorrelated = 2.0 / math.sqrt(math.pi)
    if share.verdict == NO_SIGNAL:
        return AboveNoise(0.0, 0.0, decorrelated, NO_SIGNAL)
    s1_above = above_noise(s1, s1_noise)
    signal_sq = s1 * s1 - s1_noise.value**2
    if s1_above.verdict == LOW or share.verdict == LOW or signal_sq <= 0.0:
        # S1 one spread above the floor would give this much
        bound = s3 * math.sqrt(max((s1_noise.value + s1_noise.spread) ** 2 - s1_noise.value**2, 0.0)) / max(s1, 1e-300)
        return AboveNoise(0.0, bound, decorrelated, LOW)
    signal = math.sqrt(signal_sq)
    value = s3 * (signal / s1) / math.sqrt(share.value)
    spread = value * math.hypot(s1 * s1_noise.spread / signal_sq, share.spread / (2.0 * share.value))
    return AboveNoise(value, spread, decorrelated, OK)


def tau_verdict(status: int, share: AboveNoise) -> str:
    """τc's verdict: ``no_signal`` (σ = 0), ``low`` (the fit found nothing to time, BELOW, or the
    signal share is within the noise) or ``ok``. ``status`` is the fit's (correlation_time)."""
    if status == TAU_NO_SIGNAL or share.verdict == NO_SIGNAL:
        return NO_SIGNAL
    if status == BELOW or share.verdict == LOW:
        return LOW
    return OK
