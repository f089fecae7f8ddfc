"""Correlation time τc from the normalised intensity autocorrelation (batch reference).

The simulator's scenes (paper §2A) draw the object phase as a random walk with step
χ·sqrt(Δt/τc), so the field correlates as exp(-k/(2τc)) and the intensity (fully developed
speckle, g2 - 1 = |g1|²) as ρ(k) = exp(-k/τc): the τc of a scene is the e-folding time of the
intensity autocorrelation, in frames. That is what :func:`tau_c` returns.

Per pixel, over a window of N frames with the window mean Ī subtracted::

    Ĉ(k) = [Σ_{t=1}^{N-k} (I_t - Ī)(I_{t+k} - Ī) / (N-k)] / [Σ_t (I_t - Ī)² / N],  k in tau_lags(K)

is fitted to the *expected value* of that estimator under the model
γ(u)/γ(0) = A·exp(-|u|/τ) for u != 0 (A <= 1: white noise, i.e. shot noise, uncorrelated phase
noise and ambient photons, lowers every lag k >= 1 by the same factor and so only A). The
expected value includes the finite-N bias of the mean subtraction (docs/tau_c.md derives it)::

    E[Ĉ(k)] ≈ ((1-A)·a + A·b_k(τ)) / ((1-A)·c + A·d(τ)),   a = -1/N, c = 1 - 1/N,
    b_k = r^k - 2·X_k/(N(N-k)) + S/N²,  d = 1 - S/N²,  r = exp(-1/τ),
    S = N(1+r)/(1-r) - 2r(1-r^N)/(1-r)²,   X_k = (N-k)(1+r)/(1-r) - r(1-r^(N-k))(1+r^k)/(1-r)²

The fit minimises Σ_k (Ĉ(k) - E[Ĉ(k)])² over A in [0, 1] and τ. With w = A/(c + A(d - c))
the model is a/c + w·(b_k - a·d/c), linear in w: at each τ of a log grid (shared by all
pixels, so the lag sums become one matrix product) w is closed form; the best grid point is
refined by a parabola in log τ, then by one through exact residuals a quarter step apart.
The lags are a multi-tau set (:func:`tau_lags`, as dynamic-light-scattering correlators
use): every lag up to 4, then spaced by about 1.4 up to K, K included (K = 20: 9 lags, not 20).
The streaming engine's push costs one row of sums per lag, so fewer lags is what keeps τc
near the cost of S1+S2+S3; the model holds for any set of lags.
A region's τc is fitted to its pooled correlation Σ_p cov_p(k) / Σ_p var_p.
Per-pixel maps are then made median-unbiased (:func:`median_unbiased`): one pixel's fit
reads about 4.3τ/N low; regions, fitted to pooled sums, are not corrected.

Results (units: frames, i.e. Δt), with a status per value (:data:`MEASURED` ...):

- MEASURED (0): TAU_FLOOR <= τ <= K.
- ABOVE (1): the fitted τ exceeds K (no decorrelation worth the name within K lags): τ = K,
  to be read as "> K·Δt".
- BELOW (-1): no correlation left at lag 1 (fitted A·e^(-1/τ) below max(LAG1_MIN, 2/sqrt(N)),
  i.e. within noise; a fit beyond K whose measured shortest-lag Ĉ is within that noise; or
  τ < TAU_FLOOR): τ = TAU_FLOOR, to be read as "< TAU_FLOOR·Δt".
- NO_SIGNAL (2): σ = 0 (constant, dead or saturated pixel): τ = 0.0; regions leave such
  pixels out (all of them constant: τ = 0.0, NO_SIGNAL).

Never NaN or inf.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from edgedsm.errors import EstimatorError
from edgedsm.estimators import registry
from edgedsm.estimators.batch import check_frames

MEASURED, ABOVE, BELOW, NO_SIGNAL = 0, 1, -1, 2
TAU_FLOOR = 1.0 / 3.0  # frames: e^-3 = 5 % correlation left after one frame
#: Window modes τc can be estimated in: its finite-window bias correction models a window of N
#: equally weighted frames, which an exponential window is not.
TAU_MODES = tuple(sorted(registry.get("tau_c").modes))  # the registry's


def longest_lag(window: int) -> int:
    """The longest lag K an N-frame window allows: N - 2 (the fit needs K < N - 1)."""
    return window - 2


def max_lag_problem(max_lag: int, window: int) -> str | None:
    """Why K = ``max_lag`` does not fit an N-frame window (None: it does); the one statement of it."""
    if 1 <= max_lag <= longest_lag(window):
        return None
    return f"max_lag K={max_lag} does not fit a window of N={window} frames (need 1 <= K <= N-2)"


def default_max_lag(window: int) -> int:
    """K, the longest τc lag in frames when none is given: N/2 (rounded down, at least 1, at most
    N - 2). The multi-tau lags make the count grow as log K (N = 200: 14 lags up to 100, against 9
    up to 20), so a slow process is timed up to N/2·Δt for about the cost of a short ladder;
    beyond N/2 fewer than N/2 pairs are left per lag and the window-mean bias dominates."""
    return max(1, min(window // 2, longest_lag(window)))


def tau_threshold_problem(wet_below_s: float, dry_above_s: float, hysteresis: float, lags: int,
                          frame_interval_s: float) -> str | None:
    """Why τc thresholds cannot be told apart at this frame interval (None: they can). τc is measured
    from TAU_FLOOR·Δt (Δt/3) up to K·Δt; beyond, only a bound is known (docs/tau_c.md)."""
    top = lags * frame_interval_s
    floor = TAU_FLOOR * frame_interval_s
    # dry is entered at τc >= dry_above_s/(1-h), wet at τc <= wet_below_s/(1+h) (the hysteresis
    # is relative on 1/τc); "above K" reads as τc = K·Δt, "below the floor" as Δt/3
    if dry_above_s / (1 - hysteresis) > top:
        return (f"dry_above_s ({dry_above_s:g} s; {dry_above_s / (1 - hysteresis):.4g} s with the hysteresis) is "
                f"beyond the longest τc measured, estimator.max_lag x Δt = {lags} x {frame_interval_s:g} s = "
                f"{top:g} s: raise max_lag (and window) or lower dry_above_s")
    if wet_below_s / (1 + hysteresis) < floor:
        return (f"wet_below_s ({wet_below_s:g} s; {wet_below_s / (1 + hysteresis):.4g} s with the hysteresis) is "
                f"below the shortest τc measured, Δt/3 = {floor:.4g} s: a faster camera is needed")
    return None


def tau_mode_problem(mode: str) -> str | None:
    """Why τc cannot be estimated in window ``mode`` (None: it can); the one statement of it."""
    return registry.mode_problem("tau_c", mode)
LAG1_MIN = 0.05  # fitted lag-1 correlation below this: nothing left to time
DENSE_LAGS = 4  # every lag up to this one
LAG_FACTOR = 1.4  # then each lag about this factor above the previous (rounded)
_GRID_STEP = 2.0 ** (1.0 / 16.0)  # 4.4 % between grid values of τ
_GRID_TOP = 8.0  # the grid reaches 8·K: a minimum there is far beyond K anyway
_CHUNK = 1 << 14  # pixels per fitting chunk: (chunk, grid) float64 temporaries of a few MiB
# per-pixel fits: median(τ̂) ≈ τ·(1 - PIXEL_BIAS·τ/N) (Monte Carlo of the model, docs/tau_c.md and
# scripts/tau_pixel_bias.py: 4.5 with all lags 1..K; the multi-tau lags read 4 % less, so 4.3)
PIXEL_BIAS = 4.3


class TauC(NamedTuple):
    """τc (frames) and its status (MEASURED, ABOVE, BELOW, NO_SIGNAL): (H, W) arrays, or
    a float and an int for a region."""

    tau: np.ndarray | float
    status: np.ndarray | int


# ----------------------------------------------------------------------------- lags
def tau_lags(max_lag: int) -> np.ndarray:
    """The lags (frames, int64, increasing) τc is fitted at, K = ``max_lag`` the longest.

    Multi-tau, as dynamic-light-scattering correlators space their channels: every lag up to
    DENSE_LAGS, then each about LAG_FACTOR times the one before (rounded half up), then K
    itself; a lag closer to K than sqrt(LAG_FACTOR) gives way to K (no near-duplicate pair at
    the end) unless that would leave a gap wider than LAG_FACTOR^1.5.
    K = 20: 1, 2, 3, 4, 6, 8, 11, 15, 20; K = 10: 1, 2, 3, 4, 6, 8, 10; K = 16:
    1, 2, 3, 4, 6, 8, 11, 16. A decay exp(-k/τ) is sampled about as densely per e-folding at
    every τ <= K, with the short lags, where the correlation is largest, all kept.
    """
    top = int(max_lag)
    if top < 1:
        raise EstimatorError(f"max_lag must be >= 1, got {max_lag!r}")
    lags = list(range(1, min(top, DENSE_LAGS) + 1))
    factor_tenths = round(LAG_FACTOR * 10)
    while lags[-1] < top:
        step = (lags[-1] * factor_tenths + 5) // 10  # round(1.4·previous), exact integers
        if step >= top:
            # K² < 1.4·previous²: K is within sqrt(1.4) of the previous lag, which it replaces
            # if K² <= 1.4³·(the lag before)²
            if (len(lags) > DENSE_LAGS and top * top * 10 < factor_tenths * lags[-1] ** 2
                    and top * top * 1000 <= factor_tenths**3 * lags[-2] ** 2):
                lags.pop()
            lags.append(top)
        else:
            lags.append(step)
    return np.array(lags, np.int64)


def _default_lags(lags: np.ndarray | None, rows: int) -> np.ndarray:
    """The lags of ``rows`` rows of correlations: ``lags``, or 1..rows."""
    if lags is None:
        return np.arange(1, rows + 1, dtype=np.int64)
    lags = np.asarray(lags, np.int64)
    if lags.shape != (rows,):
        raise EstimatorError(f"{lags.size} lags for {rows} rows of correlations")
    return lags


# ----------------------------------------------------------------------------- model
def expected_correlation(tau: np.ndarray | float, amplitude: np.ndarray | float, n: int,
                         lags: np.ndarray) -> np.ndarray:
    """E[Ĉ(k)] of an N-frame window for ρ = A·exp(-k/τ) (ratio of expectations), shape
    (len(lags),) + broadcast(tau, amplitude).shape."""
    tau_arr = np.asarray(tau, np.float64)
    amp = np.asarray(amplitude, np.float64)
    b, d = _biased_terms(tau_arr, n, np.asarray(lags))
    a, c = -1.0 / n, 1.0 - 1.0 / n
    return ((1.0 - amp) * a + amp * b) / ((1.0 - amp) * c + amp * d)


def _biased_terms(tau: np.ndarray, n: int, lags: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """b_k(τ) and d(τ) of the module docstring; b has shape (len(lags),) + tau.shape."""
    inv = 1.0 / tau
    r = np.exp(-inv)
    one_minus_r = -np.expm1(-inv)  # 1 - r without cancellation for large τ
    ratio = (1.0 + r) / one_minus_r
    edge = r / (one_minus_r * one_minus_r)
    total = n * ratio - 2.0 * edge * -np.expm1(-n * inv)  # S = Σ_t Σ_u r^|t-u|
    k = lags.reshape((-1,) + (1,) * tau.ndim).astype(np.float64)
    m = n - k
    cross = m * ratio - edge * -np.expm1(-m * inv) * (1.0 + np.exp(-k * inv))  # X_k
    b = np.exp(-k * inv) - 2.0 * cross / (n * m) + total / (n * n)
    d = 1.0 - total / (n * n)
    return b, d


def tau_grid(max_lag: int) -> np.ndarray:
    """The log grid of τ (frames) the fit searches: TAU_FLOOR/2 ... 8·K, step 2^(1/16)."""
    low, high = TAU_FLOOR / 2.0, _GRID_TOP * max_lag
    count = math.ceil(math.log(high / low) / math.log(_GRID_STEP)) + 1
    return low * _GRID_STEP ** np.arange(count, dtype=np.float64)


# ----------------------------------------------------------------------------- fit
def fit_correlations(corr: np.ndarray, n: int, lags: np.ndarray | None = None,
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fit Ĉ(k) at ``lags`` (array (L, P), row j at lag lags[j]; default lags 1..L) of N-frame
    windows: (τ, A, status), each (P,). K = lags[-1] is the longest lag (ABOVE beyond it).

    NO_SIGNAL (σ = 0) is the caller's to set. Deterministic: equal inputs give bit-identical
    outputs (this is what makes the streaming maps equal the batch ones).
    """
    corr = np.asarray(corr, np.float64)
    rows, pixels = corr.shape
    lags = _default_lags(lags, rows)
    grid = tau_grid(int(lags[-1]))
    b, d = _biased_terms(grid, n, lags)  # (L, G), (G,)
    a, c = -1.0 / n, 1.0 - 1.0 / n
    # m_k = (a + A·β_k)/(c + A·δ) with β = b - a, δ = d - c; with w = A/(c + A·δ) this is
    # m_k = a/c + w·g_k, g_k = β_k - a·δ/c: linear in w, so A is profiled out in closed form
    g = np.ascontiguousarray((b - a - a * (d - c) / c).T)  # (G, L)
    model = (g.sum(axis=1), (g * g).sum(axis=1), 1.0 / d, c, d - c)
    tau = np.empty(pixels)
    amp = np.empty(pixels)
    status = np.empty(pixels, np.int8)
    for start in range(0, pixels, _CHUNK):
        part = slice(start, min(start + _CHUNK, pixels))
        tau[part], amp[part], status[part] = _fit_chunk(corr[:, part] - a / c, grid, g, model, n, lags)
    return tau, amp, status


def _exact_residual(y: np.ndarray, tau: np.ndarray, n: int, lags: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Residual and w of the profiled fit at a τ per pixel (y: Ĉ - a/c at ``lags``, (L, P))."""
    a, c = -1.0 / n, 1.0 - 1.0 / n
    b, d = _biased_terms(tau, n, lags)
    g = b - a * d / c
    sum_gg = np.einsum("kp,kp->p", g, g)
    g_y = np.einsum("kp,kp->p", g, y)
    w = np.clip(g_y / sum_gg, 0.0, 1.0 / d)
    return np.einsum("kp,kp->p", y, y) + w * (w * sum_gg - 2.0 * g_y), w


def _parabola(left: np.ndarray, mid: np.ndarray, right: np.ndarray) -> np.ndarray:
    """Vertex offset (in steps, within ±1/2) of the parabola through three equally spaced values."""
    curvature = left - 2.0 * mid + right
    bend = curvature > 0.0
    offset = np.where(bend, 0.5 * (left - right) / np.where(bend, curvature, 1.0), 0.0)
    return np.clip(offset, -0.5, 0.5)


def _fit_chunk(y: np.ndarray, grid: np.ndarray, g: np.ndarray,
               model: tuple[np.ndarray, np.ndarray, np.ndarray, float, np.ndarray], n: int,
               lags: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least squares over w at every grid τ (y: Ĉ - a/c at ``lags``, (L, P)), best grid point, then a
    parabola through its neighbours in log τ, then one more parabola through exact residuals
    a quarter step apart. w is kept in [0, 1/d], i.e. A in [0, 1]."""
    _, sum_gg, w_top, c, delta = model
    a = -1.0 / n
    sum_yy = np.einsum("kp,kp->p", y, y)[:, None]  # (P, 1)
    g_y = y.T @ g.T  # (P, G): Σ_k g_k(τ_g)·y_k, the one O(L·G) step
    w = np.clip(g_y / sum_gg, 0.0, w_top)
    resid = sum_yy + w * (w * sum_gg - 2.0 * g_y)
    best = np.argmin(resid, axis=1)
    rows = np.arange(y.shape[1])
    inner = np.clip(best, 1, grid.size - 2)
    on_grid_edge = best != inner  # minimum on the grid's edge: no parabola
    offset = _parabola(resid[rows, inner - 1], resid[rows, inner], resid[rows, inner + 1])
    offset[on_grid_edge] = 0.0
    tau = grid[best] * _GRID_STEP**offset
    fine = _GRID_STEP**0.25
    middle = ~on_grid_edge
    if middle.any():
        yy, centre = y[:, middle], tau[middle]
        steps = [_exact_residual(yy, centre * fine**j, n, lags)[0] for j in (-1, 0, 1)]
        tau[middle] = centre * fine ** _parabola(*steps)
    w_best = w[rows, best]
    fitted_amp = w_best * c / (1.0 - w_best * delta[best])  # A = w·c/(1 - w·δ)
    lag_max = float(lags[-1])
    status = np.full(y.shape[1], MEASURED, np.int8)
    # nothing to time: the fitted correlation left at the shortest lag is within noise (2/sqrt(N)
    # is two standard errors of a white-noise sample correlation) or below LAG1_MIN. A fit beyond
    # K needs the *measured* one above it too: a white-noise pixel's long lags scatter by
    # 1/sqrt(N-k), and a slow decay with a large amplitude (which the window-mean bias bends
    # below zero there) can fit that scatter better than no correlation at all; it read "above
    # K" for 11 % of pure-noise pixels at K = N/2 = 100 (docs/tau_c.md, "The longest lag")
    noise = max(LAG1_MIN, 2.0 / math.sqrt(n))
    beyond = (best == grid.size - 1) | (tau > lag_max)
    below = (tau < TAU_FLOOR) | (fitted_amp * np.exp(-1.0 / tau) < noise) | (beyond & (y[0] + a / c < noise))
    above = ~below & beyond
    status[above] = ABOVE
    status[below] = BELOW
    tau = np.where(above, lag_max, np.where(below, TAU_FLOOR, tau))
    return tau, fitted_amp, status


# ----------------------------------------------------------------------------- sums
def covariances_from_sums(n: int, total: np.ndarray, total_sq: np.ndarray, products: np.ndarray,
                          edges: np.ndarray, lags: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lagged covariances and variance of N-frame windows from exact integer sums:
    (cov (L, P), var (P,)), cov[j] = Σ_{t<=N-k}(I_t - Ī)(I_{t+k} - Ī)/(N-k) at k = lags[j],
    var = Σ(I_t - Ī)²/N.

    total = ΣI, total_sq = ΣI², products[j] = Σ_{t=1}^{N-k} I_t·I_{t+k}, edges[j] = sum of
    the first k and the last k frames, k = lags[j]; all int64, (P,) or (L, P). The sums are re-centred on
    the integer c = round(ΣI/N) in int64 (modulo 2^64: exact whenever the centred result fits,
    which it does while N·(2^bits - 1)² < 2^63), then the float64 steps are the same for the
    batch and streaming engines, so both give bit-identical results. var is exactly 0 where
    σ = 0.
    """
    rows, pixels = products.shape
    lags = _default_lags(lags, rows)
    cov = np.empty((rows, pixels))
    var = np.empty(pixels)
    step = max(1, _CHUNK // 4)  # pixels per chunk: the (L, chunk) temporaries stay in cache
    for start in range(0, pixels, step):
        part = slice(start, start + step)
        cov[:, part], var[part] = _covariances_chunk(n, total[part], total_sq[part], products[:, part],
                                                     edges[:, part], lags)
    return cov, var


def _covariances_chunk(n: int, total: np.ndarray, total_sq: np.ndarray, products: np.ndarray,
                       edges: np.ndarray, lags: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    k = lags[:, None]
    total = total.astype(np.int64)
    centre = np.floor(total / n + 0.5).astype(np.int64)  # c
    rest = total - centre * n  # r = Σ(I - c), |r| <= N/2 + 1
    centred_sq = total_sq.astype(np.int64) - centre * (total + rest)  # Σ(I - c)²
    inner = 2 * total - edges.astype(np.int64)  # Σ_{t<=N-k} I_t + Σ_{t>k} I_t
    inner_c = inner - 2 * (n - k) * centre  # the same of I - c
    products_c = products.astype(np.int64) - centre * inner + (n - k) * centre * centre
    mean_c = rest / n  # Ī - c
    spread = np.maximum(centred_sq - rest * mean_c, 0.0)  # Σ(I - Ī)², 0 exactly when σ = 0
    numerator = products_c - mean_c * inner_c + (n - k) * mean_c * mean_c
    return numerator / (n - k), spread / n


def normalise(cov: np.ndarray, var: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Ĉ(k) = cov/var per pixel, and valid = var > 0 (Ĉ = 0 where σ = 0)."""
    valid = var > 0.0
    return cov * np.where(valid, 1.0 / np.where(valid, var, 1.0), 0.0), valid


def _integer_sums(stack: np.ndarray, lags: np.ndarray) -> tuple[np.ndarray, ...]:
    """ΣI, ΣI², the lag products and the edge sums at ``lags`` (see covariances_from_sums),
    int64 exact."""
    n = stack.shape[0]
    top = int(lags[-1])
    flat = stack.reshape(n, -1).astype(np.int64)
    total = flat.sum(axis=0)
    total_sq = np.einsum("tp,tp->p", flat, flat)
    products = np.empty((lags.size, flat.shape[1]), np.int64)
    edges = np.empty_like(products)
    head = np.cumsum(flat[:top], axis=0)  # first k frames, k = 1..K
    tail = np.cumsum(flat[::-1][:top], axis=0)  # last k frames
    for j, k in enumerate(lags.tolist()):
        products[j] = np.einsum("tp,tp->p", flat[:-k], flat[k:])
        edges[j] = head[k - 1] + tail[k - 1]
    return total, total_sq, products, edges


def _float_covariances(stack: np.ndarray, lags: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cov (L, P) at ``lags`` and var (P,) of float data, two-pass and mean-centred in float64."""
    n = stack.shape[0]
    flat = stack.reshape(n, -1).astype(np.float64)
    centred = flat - flat.mean(axis=0)
    var = np.einsum("tp,tp->p", centred, centred) / n
    # constant pixels: the centred values are rounding residue, far below the data's scale
    var[var <= (64.0 * np.finfo(np.float64).eps * np.abs(flat).max(axis=0)) ** 2] = 0.0
    cov = np.empty((lags.size, flat.shape[1]))
    for j, k in enumerate(lags.tolist()):
        cov[j] = np.einsum("tp,tp->p", centred[:-k], centred[k:]) / (n - k)
    return cov, var


def _fits_int64(stack: np.ndarray) -> bool:
    if not np.issubdtype(stack.dtype, np.integer):
        return False
    top = int(stack.max()) if stack.size else 0
    return stack.shape[0] * top * top < 2**62


def covariances(frames: np.ndarray, max_lag: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Lagged covariances (L, H, W) at the lags ``tau_lags(K)`` and variance (H, W) of every
    pixel over the stack (see covariances_from_sums); integer data use exact integer sums, as the
    streaming engine. K = ``max_lag``, by default :func:`default_max_lag` (N/2)."""
    stack, max_lag = _check(frames, max_lag)
    n, h, w = stack.shape
    lags = tau_lags(max_lag)
    if _fits_int64(stack):
        cov, var = covariances_from_sums(n, *_integer_sums(stack, lags), lags)
    else:
        cov, var = _float_covariances(stack, lags)
    return cov.reshape(lags.size, h, w), var.reshape(h, w)


# ----------------------------------------------------------------------------- public
def _check(frames: np.ndarray, max_lag: int | None) -> tuple[np.ndarray, int]:
    """The stack and K: ``max_lag``, or the daemon's default N/2 (:func:`default_max_lag`) when None."""
    stack = check_frames(frames)
    if max_lag is None:
        max_lag = default_max_lag(stack.shape[0])
    if isinstance(max_lag, bool) or not isinstance(max_lag, int | np.integer):
        raise EstimatorError(f"max_lag must be an integer number of frames, got {max_lag!r}")
    if problem := max_lag_problem(max_lag, stack.shape[0]):
        raise EstimatorError(problem)
    return stack, int(max_lag)


def _check_mask(mask: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    region = np.asarray(mask)
    if region.dtype != np.bool_:
        raise EstimatorError(f"mask must be a boolean (H, W) array, got dtype {region.dtype}")
    if region.shape != shape:
        raise EstimatorError(f"mask shape {region.shape} does not match the frames' {shape}")
    if not region.any():
        raise EstimatorError("mask selects no pixel")
    return region


def fit_region(cov: np.ndarray, var: np.ndarray, mask: np.ndarray, n: int, lags: np.ndarray) -> TauC:
    """τc of a region (cov (L, H, W) at ``lags``, var and mask (H, W)) from its pooled correlation
    Σ_p cov_p(k) / Σ_p var_p: averaging before dividing keeps the ratio's own bias (of order
    τ/N per pixel) out; pixels with σ = 0 add nothing."""
    return fit_pooled(np.ascontiguousarray(cov[:, mask]), var[mask], n, lags)


def fit_pooled(cov: np.ndarray, var: np.ndarray, n: int, lags: np.ndarray) -> TauC:
    """τc of the pixels given as cov (L, M) at ``lags`` and var (M,), pooled (see fit_region)."""
    pooled_var = float(np.ascontiguousarray(var).sum())
    if pooled_var <= 0.0:
        return TauC(0.0, NO_SIGNAL)
    pooled = np.ascontiguousarray(cov).sum(axis=1)[:, None] / pooled_var  # one summation order
    tau, _, status = fit_correlations(pooled, n, lags)
    return TauC(float(tau[0]), int(status[0]))


def median_unbiased(tau: np.ndarray, n: int) -> np.ndarray:
    """Per-pixel τ̂ (frames) of N-frame windows corrected for the fit's small-sample bias.

    One pixel holds about N/(2τ) independent speckle realisations; its least-squares τ̂ is a
    nonlinear function of noisy covariances and its median lies below τ by about
    PIXEL_BIAS·τ/N (docs/tau_c.md: -20 % at N = 20τ). As Andrews' median-unbiased AR(1)
    estimator (Econometrica 61, 1993) this inverts the median function τ ↦ τ(1 - cτ/N):
    τ = (N/2c)(1 - sqrt(1 - 4cτ̂/N)) = 2τ̂/(1 + sqrt(1 - 4cτ̂/N)), monotone in τ̂, so the median
    of the corrected map is the corrected median. Beyond τ̂ = N/(4c), where the median
    function has no inverse, the correction stays at its largest factor, 2.
    """
    root = np.sqrt(np.maximum(1.0 - 4.0 * PIXEL_BIAS * tau / n, 0.0))
    return 2.0 * tau / (1.0 + root)


def fit_map(cov: np.ndarray, var: np.ndarray, n: int, lags: np.ndarray) -> TauC:
    """Per-pixel τc and status from cov (L, H, W) at ``lags`` and var (H, W); measured values
    are median-unbiased (:func:`median_unbiased`), which may move a pixel to ABOVE."""
    rows, h, w = cov.shape
    corr, valid = normalise(cov.reshape(rows, h * w), var.reshape(-1))
    tau, _, status = fit_correlations(corr, n, lags)
    measured = status == MEASURED
    tau[measured] = median_unbiased(tau[measured], n)
    longest = float(lags[-1])
    above = measured & (tau > longest)
    tau[above] = longest
    status[above] = ABOVE
    tau[~valid] = 0.0
    status[~valid] = NO_SIGNAL
    return TauC(tau.reshape(h, w), status.reshape(h, w))


def tau_c_bounds(frames: np.ndarray, max_lag: int | None = None, mask: np.ndarray | None = None) -> TauC:
    """τc (frames) with its status: MEASURED, ABOVE (τ = K, read "> K·Δt"), BELOW (τ =
    TAU_FLOOR) or NO_SIGNAL (σ = 0, τ = 0.0). Per pixel ((H, W) arrays), or for the boolean
    (H, W) ``mask`` from the region-averaged correlations (a float and an int). K = ``max_lag``,
    by default N/2 as the daemon's (:func:`default_max_lag`)."""
    stack, max_lag = _check(frames, max_lag)
    region = None if mask is None else _check_mask(mask, stack.shape[1:])
    cov, var = covariances(stack, max_lag)
    n, lags = stack.shape[0], tau_lags(max_lag)
    if region is None:
        return fit_map(cov, var, n, lags)
    return fit_region(cov, var, region, n, lags)


def tau_c(frames: np.ndarray, max_lag: int | None = None, mask: np.ndarray | None = None) -> np.ndarray | float:
    """Correlation time τc in frames (Δt) from an (N, H, W) stack: an (H, W) float64 map, or
    with a boolean (H, W) ``mask`` the region's τc from its averaged correlations.

    Fits A·exp(-k/τ) with the finite-N bias of the window mean corrected, at the lags
    ``tau_lags(K)`` (1, 2, 3, 4, then spaced by about 1.4, up to K, 1 <= K <= N-2). K =
    ``max_lag`` frames, by default N/2 (:func:`default_max_lag`, as the daemon's
    ``estimator.max_lag`` and the streaming engine's): τc above K reads K. Degenerate values:
    see :func:`tau_c_bounds` (which also tells which values are bounds rather than measurements).

    Args:
        frames: (N, H, W) stack, N >= 3, integer or float, finite and >= 0.
        max_lag: K in frames, or None for N/2.
        mask: a boolean (H, W) region, or None for a per-pixel map.

    Returns:
        τc in frames: an (H, W) float64 map, or a float with ``mask``.
    """
    return tau_c_bounds(frames, max_lag, mask).tau
