"""τc in the streaming engine: the integer sums it keeps, and how they become the batch inputs.

Per pixel, sliding and tumbling windows keep, besides ΣI and ΣI² (shared with S3), the K lag
products Σ_{t=1}^{N-k} I_t·I_{t+k} (k = 1..K), one row of pixels per lag. A push adds
I_i·I_{i-k} for each k and (sliding) removes I_{i-N}·I_{i-N+k}: O(K) per pixel per frame,
exact integers. Each product sum is at most (N-1)·(2^bits - 1)², kept in int32 while that
fits (8-bit data up to N = 33 026) and in int64 otherwise, which is exact while
N·(2^bits - 1)² < 2^63 (16-bit data up to N = 2.1e9, above the engine's largest window).
The sums of the first k and last k frames of the window (the "edges" of
:func:`edgedsm.estimators.correlation_time.covariances_from_sums`) are formed when the maps are asked for
(sliding: from the ring, O(K) per pixel) or accumulated during the block (tumbling).
"""

from __future__ import annotations

import numpy as np

from edgedsm.estimators.correlation_time import TauC, covariances_from_sums, fit_map, fit_pooled

_INT32_MAX = 2**31 - 1


def product_dtype(window: int, bits: int) -> type[np.signedinteger]:
    """int32 when (N-1)·(2^bits - 1)² fits, else int64."""
    top = (1 << bits) - 1
    return np.int32 if (window - 1) * top * top <= _INT32_MAX else np.int64


def edges_of(frames: list[np.ndarray], lags: int) -> np.ndarray:
    """Sum of the first k plus the last k of ``frames`` (the window in time order, views of the
    ring), k = 1..K: (K, P) int64."""
    edges = np.empty((lags, frames[0].size), np.int64)
    head = np.zeros(frames[0].size, np.int64)
    tail = np.zeros(frames[0].size, np.int64)
    for k in range(lags):
        head += frames[k]
        tail += frames[-1 - k]
        edges[k] = head + tail
    return edges


def covariances(window: int, total: np.ndarray, total_sq: np.ndarray, products: np.ndarray,
                edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """cov (K, P) and var (P,) from the engine's sums (products and edges (K, P))."""
    return covariances_from_sums(window, total, total_sq, products, edges)


def tau_map(window: int, shape: tuple[int, int], cov: np.ndarray, var: np.ndarray) -> TauC:
    """Per-pixel τc and status (cov (K, P), var (P,)), as :func:`edgedsm.estimators.tau_c_bounds`."""
    return fit_map(cov.reshape((cov.shape[0], *shape)), var.reshape(shape), window)


def tau_region(window: int, cov: np.ndarray, var: np.ndarray) -> TauC:
    """τc of the pixels given (cov (K, M), var (M,)) from their pooled correlations, as
    ``tau_c_bounds(..., mask=mask)``."""
    return fit_pooled(cov, var, window)
