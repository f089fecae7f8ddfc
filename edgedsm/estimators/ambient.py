"""Ambient-light correction of S2 from dark frames (laser off): the level AND the shot noise.

Paper Eq. 2: S2 = 1/(N-m) Σ |I_i - I_{i+m}| / (I_i + I_{i+m} + q). §2B: ambient light of
N_al = η·N_max photons per pixel "strongly" lowers S2 and makes it show the beam profile, because
the ambient photons add 2·N_al to the denominator while their shot noise (variance N_al) adds
little to |ΔI|. Subtracting the dark level alone (what the daemon did) fixes the denominator but
leaves the ambient shot noise in the numerator, so dim pixels read too high (docs/ambient.md).

With the detected intensity I = L + A (laser L, ambient A independent of L, dark mean μ_d and
dark variance v_d per pixel, measured with the laser off):

* denominator: E[I_i + I_{i+m}] = E[L_i + L_{i+m}] + 2·μ_d, so the laser level is Ī - μ_d;
* numerator:  E[(ΔI)²] = E[(ΔL)²] + 2·v_d exactly (the ambient differences are independent of
  the laser's), and with E|ΔL| ≈ E|ΔI|·sqrt(E[(ΔL)²]/E[(ΔI)²]) (same shape of distribution)
  E|ΔL| ≈ E|ΔI|·sqrt(1 - 2·v_d/E[(ΔI)²]).

The correction is applied to the finished S2 map (a ratio of means correction of a mean of ratios;
docs/ambient.md measures how well that holds). It is the identity when μ_d = v_d = 0. S1 and S3 are
never corrected: S1 is "weakly affected" and S3 insensitive to ambient light (§2B-C).
"""

from __future__ import annotations

import numpy as np

from edgedsm.errors import EstimatorError


def _as_map(name: str, value: np.ndarray | float, shape: tuple[int, ...]) -> np.ndarray:
    array = np.broadcast_to(np.asarray(value, dtype=np.float64), shape) if np.ndim(value) == 0 \
        else np.asarray(value, dtype=np.float64)
    if array.shape != shape:
        raise EstimatorError(f"{name} must be a scalar or a {shape} map, got shape {array.shape}")
    if not np.isfinite(array).all() or (array < 0).any():
        raise EstimatorError(f"{name} must be finite and >= 0")
    return array


def mean_square_difference(frames: np.ndarray, lag: int) -> np.ndarray:
    """E[(I_i - I_{i+m})²] over the window, (H, W) float64: the numerator's second moment."""
    stack = np.asarray(frames)
    n = stack.shape[0]
    if not 1 <= lag <= n - 1:
        raise EstimatorError(f"lag m={lag} does not fit a window of N={n} frames")
    total = np.zeros(stack.shape[1:], np.float64)
    for i in range(n - lag):
        diff = stack[i].astype(np.float64) - stack[i + lag]
        total += diff * diff
    return total / (n - lag)


def ambient_corrected_s2(s2: np.ndarray, mean: np.ndarray, mean_square_diff: np.ndarray,
                         dark_mean: np.ndarray | float, dark_var: np.ndarray | float,
                         smooth: int = 1) -> np.ndarray:
    """S2 with the ambient level and the ambient shot noise removed, (H, W) float64.

    ``s2``: plain S2 map (Eq. 2); ``mean``: the window's temporal mean Ī; ``mean_square_diff``:
    E[(I_i - I_{i+m})²] at the same lag; ``dark_mean``/``dark_var``: the dark frames' mean and
    variance (per pixel or one value; all in the frames' unit). ``smooth`` > 1 box-averages Ī and
    E[(ΔI)²] over smooth x smooth pixels before forming the factors, so the correction follows the
    beam and the activity, not each speckle's noise. Defined everywhere: 0 where the
    laser level Ī - μ_d <= 0 or where the ambient noise explains all of the fluctuation.
    """
    s2 = np.asarray(s2, dtype=np.float64)
    shape = s2.shape
    mean = _as_map("mean", mean, shape)
    msd = _as_map("mean_square_diff", mean_square_diff, shape)
    mu_d = _as_map("dark_mean", dark_mean, shape)
    v_d = _as_map("dark_var", dark_var, shape)
    if smooth > 1:
        from scipy import ndimage

        mean = ndimage.uniform_filter(mean, size=smooth, mode="nearest")
        msd = ndimage.uniform_filter(msd, size=smooth, mode="nearest")
    laser = mean - mu_d
    keep = np.zeros(shape, np.float64)
    np.divide(2.0 * v_d, msd, out=keep, where=msd > 0)
    numerator_factor = np.sqrt(np.clip(1.0 - keep, 0.0, 1.0))
    numerator_factor[msd <= 0] = 1.0  # no fluctuation: S2 is 0 already
    level_factor = np.zeros(shape, np.float64)
    np.divide(mean, laser, out=level_factor, where=laser > 0)
    return s2 * numerator_factor * level_factor


def dark_statistics(dark_frames: np.ndarray, smooth: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel mean and variance (1/(K-1)) of K >= 2 dark frames, each box-averaged over
    ``smooth`` x ``smooth`` pixels (a variance from 10 frames alone is ±47 %)."""
    from scipy import ndimage

    stack = np.asarray(dark_frames, dtype=np.float64)
    if stack.ndim != 3 or stack.shape[0] < 2:
        raise EstimatorError(f"dark frames must be a (K >= 2, H, W) stack, got shape {stack.shape}")
    mean = stack.mean(axis=0)
    var = stack.var(axis=0, ddof=1)
    if smooth > 1:
        mean = ndimage.uniform_filter(mean, size=smooth, mode="nearest")
        var = ndimage.uniform_filter(var, size=smooth, mode="nearest")
    return mean, var
