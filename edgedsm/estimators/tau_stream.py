"""τc in the streaming engine: the integer sums it keeps, and how they become the batch inputs.

Per pixel, sliding and tumbling windows keep, besides ΣI and ΣI² (shared with S3), the lag
products Σ_{t=1}^{N-k} I_t·I_{t+k} at the L lags k of
:func:`edgedsm.estimators.correlation_time.tau_lags` (multi-tau: 9 lags for K = 20), one row of
pixels per lag. A push adds I_i·I_{i-k} for each k and (sliding) removes I_{i-N}·I_{i-N+k}:
O(L) per pixel per frame, exact integers. Each product sum is at most (N-1)·(2^bits - 1)², kept in int32 while that
fits (8-bit data up to N = 33 026) and in int64 otherwise, which is exact while
N·(2^bits - 1)² < 2^63 (16-bit data up to N = 2.1e9, above the engine's largest window).
The sums of the first k and last k frames of the window (the "edges" of
:func:`edgedsm.estimators.correlation_time.covariances_from_sums`) are formed when the maps are asked for
(sliding: from the ring's first and last K frames, O(K) per pixel) or accumulated during the block (tumbling).
"""

from __future__ import annotations

import numpy as np

from edgedsm.errors import EstimatorError
from edgedsm.estimators.correlation_time import (
    TauC,
    covariances_from_sums,
    default_max_lag,
    fit_map,
    fit_pooled,
    max_lag_problem,
    tau_lags,
)

_INT32_MAX = 2**31 - 1


def max_lag_of(window: int, max_lag: int | None) -> int:
    """The engine's K: ``max_lag``, or the default N/2 when None; a K that does not fit the window
    is refused (K = 1 passes at N = 2, where τc is refused on its own: N < 3)."""
    if max_lag is None:
        return default_max_lag(window)
    if isinstance(max_lag, bool) or not isinstance(max_lag, int | np.integer):
        raise EstimatorError(f"max_lag K must be an integer, got {max_lag!r}")
    if (problem := max_lag_problem(int(max_lag), window)) and max_lag != 1:
        raise EstimatorError(problem)
    return int(max_lag)


def product_dtype(window: int, bits: int) -> type[np.signedinteger]:
    """int32 when (N-1)·(2^bits - 1)² fits, else int64."""
    top = (1 << bits) - 1
    return np.int32 if (window - 1) * top * top <= _INT32_MAX else np.int64


def edges_of(frames: list[np.ndarray], lags: np.ndarray) -> np.ndarray:
    """Sum of the first k plus the last k of ``frames`` (the window in time order, views of the
    ring; at least its first K and last K frames), k in ``lags`` (increasing): (L, P) int64."""
    edges = np.empty((lags.size, frames[0].size), np.int64)
    head = np.zeros(frames[0].size, np.int64)
    tail = np.zeros(frames[0].size, np.int64)
    done = 0  # head and tail hold the first and last ``done`` frames
    for j, k in enumerate(lags.tolist()):
        for step in range(done, k):
            head += frames[step]
            tail += frames[-1 - step]
        done = k
        edges[j] = head + tail
    return edges


def covariances(window: int, max_lag: int, total: np.ndarray, total_sq: np.ndarray, products: np.ndarray,
                edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cov (L, P) and var (P,) from the engine's sums (products and edges (L, P) at the lags
    ``tau_lags(max_lag)``)."""
    return covariances_from_sums(window, total, total_sq, products, edges, tau_lags(max_lag))


def tau_map(window: int, max_lag: int, shape: tuple[int, int], cov: np.ndarray, var: np.ndarray) -> TauC:
    """Per-pixel τc and status (cov (L, P), var (P,)), as :func:`edgedsm.estimators.tau_c_bounds`."""
    return fit_map(cov.reshape((cov.shape[0], *shape)), var.reshape(shape), window, tau_lags(max_lag))


def tau_region(window: int, max_lag: int, cov: np.ndarray, var: np.ndarray) -> TauC:
    """τc of the pixels given (cov (L, M), var (M,)) from their pooled correlations, as
    ``tau_c_bounds(..., mask=mask)``."""
    return fit_pooled(cov, var, window, tau_lags(max_lag))
