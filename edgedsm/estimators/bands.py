"""Frequency-band power maps (the "frequency filtering" of biospeckle papers): each pixel's
temporal fluctuation power in chosen frequency bands, and the ratio of a high to a low band.

Definition (batch, float64). For one pixel's N intensities I_k, sampled Δt apart, the
periodogram of the mean-removed series, one-sided and normalised so that it sums to the
population variance (Parseval):

    X_j = Σ_{k=0}^{N-1} (I_k - ⟨I⟩) e^{-2πi jk/N},  f_j = j / (N Δt),  j = 0 .. ⌊N/2⌋
    P_j = c_j |X_j|² / N²,  c_j = 2 for 0 < j < N/2, else 1,  so Σ_j P_j = σ² (Eq. 4).

The power in a band (lo, hi] is Σ P_j over lo < f_j <= hi, in grey levels² (the unit of σ²).
Frequencies are in Hz when Δt (seconds) is given, otherwise in cycles per frame (Nyquist 0.5).
DC (f = 0) is in no band (it carries no fluctuation: X_0 = 0). A band narrower than the
resolution 1/(N Δt) may hold no frequency; it then reads 0.

BSLTL's ``firfilterbank`` filters the intensities with FIR filters instead and returns filtered
data packs, not band powers; it is not the same quantity, so these maps do not claim BSLTL
conformance (docs/descriptors.md).
"""

from __future__ import annotations

import numpy as np

from edgedsm.errors import EstimatorError
from edgedsm.estimators.batch import check_frames


def _interval(dt: float | None) -> float:
    if dt is None:
        return 1.0
    dt = float(dt)
    if not np.isfinite(dt) or dt <= 0:
        raise EstimatorError(f"the frame interval dt must be a positive number of seconds, got {dt}")
    return dt


def frequencies(n: int, dt: float | None = None) -> np.ndarray:
    """f_j = j/(N Δt), j = 0 .. ⌊N/2⌋: Hz with Δt in seconds, else cycles per frame."""
    return np.fft.rfftfreq(n, d=_interval(dt))


def spectrum(frames: np.ndarray) -> np.ndarray:
    """(⌊N/2⌋ + 1, H, W) one-sided periodogram P_j of each pixel, summing to σ² (module doc)."""
    stack = check_frames(frames)
    n = stack.shape[0]
    if n < 2:
        raise EstimatorError(f"a spectrum needs N >= 2 frames, got N={n}")
    data = stack.astype(np.float64)
    data -= data.mean(axis=0)
    power = np.abs(np.fft.rfft(data, axis=0)) ** 2 / float(n * n)
    power[1:(n + 1) // 2] *= 2.0  # the negative frequencies' half, folded in (not DC, not Nyquist)
    return power


def band_power(frames: np.ndarray, bands: list[tuple[float, float]], dt: float | None = None) -> np.ndarray:
    """(len(bands), H, W): each pixel's power in each band (lo, hi], grey levels² (module doc);
    hi = inf reaches the Nyquist frequency whatever the rounding of f_j."""
    stack = check_frames(frames)
    members = band_members(stack.shape[0], bands, dt)
    power = spectrum(stack)
    return np.stack([power[j].sum(axis=0) for j in members])


def band_members(n: int, bands: list[tuple[float, float]], dt: float | None = None) -> list[np.ndarray]:
    """The indices j of the frequencies f_j in each band (lo, hi] of an N = ``n`` frame window
    (hi = inf reaches the Nyquist frequency); refuses a band with lo >= hi or starting at or above
    the highest frequency. The one rule of the batch maps and the streaming engine."""
    if not bands:
        raise EstimatorError("give at least one frequency band (lo, hi)")
    freq = frequencies(n, dt)
    nyquist = freq[-1] if len(freq) > 1 else 0.0
    members = []
    for band in bands:
        try:
            lo, hi = (float(value) for value in band)
        except (TypeError, ValueError):
            raise EstimatorError(f"a band is (lo, hi), two numbers, got {band!r}") from None
        if not (np.isfinite(lo) and not np.isnan(hi) and 0 <= lo < hi):
            raise EstimatorError(f"a band (lo, hi) needs 0 <= lo < hi, got ({lo}, {hi})")
        if lo >= nyquist:
            raise EstimatorError(f"band ({lo}, {hi}] starts at or above the Nyquist frequency {nyquist:.6g}"
                                 f" ({'Hz' if dt is not None else 'cycles per frame'})")
        members.append(np.flatnonzero((freq > lo) & (freq <= hi)))
    return members


def split_powers(frames: np.ndarray, dt: float | None = None, split: float | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(low, high): the power in (0, split] and in (split, Nyquist], grey levels²; ``split`` in
    Hz with ``dt`` (else cycles per frame), default half the Nyquist frequency. low + high = σ²."""
    stack = check_frames(frames)
    nyquist = 0.5 / _interval(dt)
    if split is None:
        split = nyquist / 2
    if not (np.isfinite(split) and 0 < split < nyquist):
        raise EstimatorError(f"the band split must lie between 0 and the Nyquist frequency {nyquist:.6g}, got {split}")
    low, high = band_power(stack, [(0.0, split), (split, np.inf)], dt)
    return low, high


def ratio(low: np.ndarray, high: np.ndarray, q: float = 0.0) -> np.ndarray:
    """high / (low + q), dimensionless; q >= 0 (grey levels²) keeps a near-empty low band from
    dominating, as S2's q does. 0 where low + q = 0 (with q = 0: a pixel with no low-band power,
    e.g. a constant one)."""
    q = float(q)
    if not np.isfinite(q) or q < 0:
        raise EstimatorError(f"q must be a finite number >= 0, got {q}")
    denominator = low + q
    result = np.zeros(np.shape(low), np.float64)
    np.divide(high, denominator, out=result, where=denominator > 0)
    return result
