"""τc of the regions and the τc map, in seconds, from a snapshot of the engine's sums: the one
computation the daemon's evaluator, ``analyze --timeline`` and ``tune`` publish (docs/tau_c.md,
"In the daemon").

A region's τc is fitted once to its pooled correlations Σ_p cov_p(k) / Σ_p var_p over its pixels
(:func:`edgedsm.estimators.tau_pooled.pooled_covariances`: compiled, a few ns per pixel and lag,
the GIL released), not the mean of per-pixel τ; it equals the batch reference
``tau_c_bounds(..., mask=mask)`` and the engine's own ``region_tau_c`` within rounding (~1e-15
relative: only the order of the sums differs; tested). τc is in frames; times the frame interval
Δt (s) it is in seconds.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from edgedsm.estimators.correlation_time import ABOVE, BELOW, MEASURED, NO_SIGNAL, TauC, fit_correlations, normalise
from edgedsm.estimators.snapshot import TauSnapshot, tau_covariances
from edgedsm.estimators.tau_pooled import block_covariances, pooled_covariances
from edgedsm.estimators.tau_stream import tau_map, tau_region
from edgedsm.messages import RegionTau, TauStatus

#: Published names of the estimator's statuses (``edgedsm.messages.TauStatus``).
STATUS_NAMES: dict[int, TauStatus] = {MEASURED: "measured", ABOVE: "above", BELOW: "below",
                                      NO_SIGNAL: "no_signal"}
#: The automatic τc map block keeps the map at about this many fitted values (~5 µs each).
MAP_FITS = 1 << 16


def region_fits(snapshot: TauSnapshot, pixels: Mapping[str, np.ndarray]) -> dict[str, TauC]:
    """Each region's τc (frames) and status from its pooled correlations; ``pixels``: each region's
    flat indices in the snapshot's shape."""
    out = {}
    for name, flat in pixels.items():
        cov, var = pooled_covariances(snapshot.window, snapshot.total, snapshot.total_sq, snapshot.products,
                                      snapshot.edges, snapshot.ends, flat, snapshot.lags)
        out[name] = tau_region(snapshot.window, snapshot.max_lag, cov[:, None], np.array([var]))
    return out


def in_seconds(fit: TauC, interval_s: float) -> RegionTau:
    """A region's fit as published: τc (frames) times the frame interval ``interval_s`` (s), and its
    status's name."""
    return RegionTau(tau_c_s=float(fit.tau) * interval_s, status=STATUS_NAMES[int(fit.status)])


def region_taus(snapshot: TauSnapshot, pixels: Mapping[str, np.ndarray], interval_s: float) -> dict[str, RegionTau]:
    """Each region's τc in seconds and its status (:func:`region_fits`, :func:`in_seconds`)."""
    return {name: in_seconds(fit, interval_s) for name, fit in region_fits(snapshot, pixels).items()}


def map_block(shape: tuple[int, int], configured: int | None) -> int:
    """Side b of the b×b blocks the τc map is pooled over: ``estimator.tau_c_map_block``, or the
    smallest b that keeps the map at MAP_FITS values or fewer (2048²: 8, 512²: 2, 256²: 1)."""
    if configured is not None:
        return configured
    return max(1, math.ceil(math.sqrt(shape[0] * shape[1] / MAP_FITS)))


def map_seconds(snapshot: TauSnapshot, interval_s: float, block: int = 1) -> np.ndarray:
    """The τc map in seconds, in the snapshot's shape (bounds where the status says so; 0 without
    signal). ``block`` 1: per pixel (median-unbiased, ~6 µs per pixel); b > 1: one value per b×b
    block from its pooled correlations, as a region's, repeated over the block's pixels (b² times
    fewer fits, and the pooled value's smaller bias)."""
    if block == 1:
        cov, var = tau_covariances(snapshot)
        return np.asarray(tau_map(snapshot.window, snapshot.max_lag, snapshot.shape, cov, var).tau) * interval_s
    cov, var = block_covariances(snapshot.window, snapshot.shape, block, snapshot.total, snapshot.total_sq,
                                 snapshot.products, snapshot.edges, snapshot.ends, snapshot.lags)
    lags, rows, cols = cov.shape
    corr, valid = normalise(cov.reshape(lags, -1), var.reshape(-1))
    tau, _, _ = fit_correlations(corr, snapshot.window, snapshot.lags)
    tau = np.where(valid, tau, 0.0).reshape(rows, cols)  # NO_SIGNAL: 0, as fit_map
    full = np.repeat(np.repeat(tau, block, axis=0), block, axis=1)[:snapshot.shape[0], :snapshot.shape[1]]
    return np.ascontiguousarray(full) * interval_s
