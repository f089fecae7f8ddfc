"""Monte Carlo of the per-pixel τc bias that PIXEL_BIAS corrects (docs/tau_c.md, "Per-pixel maps").

Each series is the intensity of a complex Gaussian AR(1) field (|g1(k)| = exp(-k/(2τ)), so the
intensity correlation is exp(-k/τ), as in the simulator), optionally mixed with a white field
of power 1 - sqrt(0.6) (intensity correlation amplitude A = 0.6). Every series is fitted alone,
as one pixel of the map, and c is read from the median: med(τ̂) = τ(1 - cτ/N). Both lag sets
are fitted on the same series: all lags 1..K, and the multi-tau lags tau_lags(K).

    PYTHONPATH=. python scripts/tau_pixel_bias.py [series]
"""

from __future__ import annotations

import sys

import numpy as np

from edgedsm.estimators.correlation_time import _float_covariances, fit_correlations, normalise, tau_lags


def intensities(tau: float, n: int, series: int, correlated: float, rng: np.random.Generator) -> np.ndarray:
    """(n, series) intensities; ``correlated``: power fraction of the AR(1) field."""
    r = np.exp(-0.5 / tau)
    field = np.empty((n, series), np.complex128)
    noise = (rng.standard_normal((n, series)) + 1j * rng.standard_normal((n, series))) / np.sqrt(2.0)
    field[0] = noise[0]
    for t in range(1, n):
        field[t] = r * field[t - 1] + np.sqrt(1.0 - r * r) * noise[t]
    white = (rng.standard_normal((n, series)) + 1j * rng.standard_normal((n, series))) / np.sqrt(2.0)
    mixed = np.sqrt(correlated) * field + np.sqrt(1.0 - correlated) * white
    return np.abs(mixed) ** 2


def bias_constant(stack: np.ndarray, tau: float, lags: np.ndarray) -> float:
    """c of the median of the per-series fits (uncorrected), statuses included as fitted."""
    n = stack.shape[0]
    cov, var = _float_covariances(stack[:, :, None], lags)
    corr, _ = normalise(cov.reshape(lags.size, -1), var.reshape(-1))
    fitted, _, _ = fit_correlations(corr, n, lags)
    return float((1.0 - np.median(fitted) / tau) * n / tau)


def main(series: int) -> None:
    rng = np.random.default_rng(2026)
    print("| τ | field | N | K | c, lags 1..K | c, multi-tau lags |")
    print("|---:|---|---:|---:|---:|---:|")
    for correlated, name in ((1.0, "full"), (np.sqrt(0.6), "A = 0.6")):
        for tau in (5.0, 10.0, 20.0, 50.0):
            for ratio in (20, 40):
                n = int(ratio * tau)
                top = max(20, int(2 * tau))
                stack = intensities(tau, n, series, correlated, rng)
                every = bias_constant(stack, tau, np.arange(1, top + 1))
                multi = bias_constant(stack, tau, tau_lags(top))
                print(f"| {tau:g} | {name} | {n} | {top} | {every:.2f} | {multi:.2f} |", flush=True)


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 4000)
