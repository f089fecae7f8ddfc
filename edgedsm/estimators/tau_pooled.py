"""Pooled τc covariances straight from the engine's integer sums: per region, or per block of a map.

A region's τc (and a block-pooled map's) is fitted to Σ_p cov_p(k) / Σ_p var_p over its pixels
(docs/tau_c.md). Forming every pixel's covariances first (``tau_covariances``, numpy: ~1 µs per
pixel with K = 20, seconds per 2048² frame) and summing them afterwards would keep the daemon's
evaluator busy for seconds; these compiled loops (GIL released) form each pixel's covariances
with the same arithmetic as :func:`edgedsm.estimators.correlation_time.covariances_from_sums`
(integer re-centring on c = round(ΣI/N), then float64) and add them into the pool at once, in
a few ns per pixel and lag. Only the summation order differs from numpy's, so pooled values
agree to rounding (~1e-15 relative, tested), not bit for bit.

Inputs as :class:`edgedsm.estimators.snapshot.TauSnapshot` holds them: ΣI and ΣI² (P,),
products (L, P) at the lags ``tau_lags(K)`` (``lags``), and either the edge sums (L, P) or the
window's first K and last K frames in time order (2K, P) from which the edge sums are formed
per pixel. Units: intensity² (counts²).
Without numba (the optional ``fast`` extra) the same pools come from ``covariances_from_sums``
in chunks (numpy; the slower path).
"""

from __future__ import annotations

import math

import numpy as np

from edgedsm.estimators.correlation_time import covariances_from_sums
from edgedsm.estimators.jit import compiled
from edgedsm.estimators.tau_stream import edges_of

try:
    import numba
except ImportError:  # the 'fast' extra is not installed: numpy below
    numba = None

_CHUNK = 1 << 14  # pixels per numpy chunk

#: Pixels handled lag by lag at a time: each of the L + 2K sum rows is then read as one short
#: sequential run per chunk (pixel by pixel over all rows, the 60 streams defeat the prefetcher).
CHUNK = 256


@compiled(inline="always")
def _add_chunk(n: int, lag_values: np.ndarray, pixels: np.ndarray, slots: np.ndarray, count: int, total: np.ndarray,
               total_sq: np.ndarray, products: np.ndarray, edges: np.ndarray, ends: np.ndarray, use_ends: bool,
               cov: np.ndarray, var: np.ndarray, scratch: np.ndarray, head: np.ndarray, tail: np.ndarray) -> None:
    """Add the (N-k)·cov(k) of pixels[:count] into cov[j, slots[i]] (k = lag_values[j]) and their
    N·var into var[slots[i]] (the divisions are the same for every pixel: the caller makes them
    once per pool). scratch (3, CHUNK) float64, head and tail (CHUNK,) int64 are work space."""
    lags = products.shape[0]
    last = 2 * lag_values[lags - 1] - 1  # ends: the first K frames, then the last K
    for i in range(count):
        p = pixels[i]
        t = np.int64(total[p])
        centre = np.int64(math.floor(t / n + 0.5))
        rest = t - centre * n
        centred_sq = np.int64(total_sq[p]) - centre * (t + rest)
        mean_c = rest / n
        var[slots[i]] += max(centred_sq - rest * mean_c, 0.0)
        scratch[0, i] = t
        scratch[1, i] = centre
        scratch[2, i] = mean_c
        head[i] = 0
        tail[i] = 0
    done = 0  # head and tail hold the first and last ``done`` frames
    for j in range(lags):
        k = lag_values[j]
        for i in range(count):
            p = pixels[i]
            t = np.int64(scratch[0, i])
            centre = np.int64(scratch[1, i])
            mean_c = scratch[2, i]
            if use_ends:
                for step in range(done, k):  # advance the sums of the first and last frames to k
                    head[i] += np.int64(ends[step, p])
                    tail[i] += np.int64(ends[last - step, p])
                edge = head[i] + tail[i]
            else:
                edge = np.int64(edges[j, p])
            inner = 2 * t - edge
            inner_c = inner - 2 * (n - k) * centre
            products_c = np.int64(products[j, p]) - centre * inner + (n - k) * centre * centre
            cov[j, slots[i]] += products_c - mean_c * inner_c + (n - k) * mean_c * mean_c
        done = k


@compiled(parallel=True, nogil=True)
def _pooled_indices(n: int, lag_values: np.ndarray, pixels: np.ndarray, total: np.ndarray, total_sq: np.ndarray,
                    products: np.ndarray, edges: np.ndarray, ends: np.ndarray, use_ends: bool,
                    parts: int) -> tuple[np.ndarray, np.ndarray]:
    lags = products.shape[0]
    cov = np.zeros((lags, parts))
    var = np.zeros(parts)
    size = (pixels.size + parts - 1) // parts
    for part in numba.prange(parts):
        scratch = np.empty((3, CHUNK))
        head = np.empty(CHUNK, np.int64)
        tail = np.empty(CHUNK, np.int64)
        slots = np.full(CHUNK, part, np.int64)
        stop = min(pixels.size, (part + 1) * size)
        for lo in range(part * size, stop, CHUNK):
            count = min(CHUNK, stop - lo)
            _add_chunk(n, lag_values, pixels[lo:lo + count], slots, count, total, total_sq, products, edges, ends,
                       use_ends, cov, var, scratch, head, tail)
    return cov, var


@compiled(parallel=True, nogil=True)
def _pooled_blocks(n: int, lag_values: np.ndarray, width: int, block: int, total: np.ndarray, total_sq: np.ndarray,
                   products: np.ndarray, edges: np.ndarray, ends: np.ndarray,
                   use_ends: bool) -> tuple[np.ndarray, np.ndarray]:
    lags = products.shape[0]
    height = total.size // width
    rows, cols = (height + block - 1) // block, (width + block - 1) // block
    cov = np.zeros((lags, rows * cols))
    var = np.zeros(rows * cols)
    for row_block in numba.prange(rows):  # one thread owns a row of blocks: no shared writes
        scratch = np.empty((3, CHUNK))
        head = np.empty(CHUNK, np.int64)
        tail = np.empty(CHUNK, np.int64)
        pixels = np.empty(CHUNK, np.int64)
        slots = np.empty(CHUNK, np.int64)
        for y in range(row_block * block, min(height, (row_block + 1) * block)):
            for x0 in range(0, width, CHUNK):
                count = min(CHUNK, width - x0)
                for i in range(count):
                    pixels[i] = y * width + x0 + i
                    slots[i] = row_block * cols + (x0 + i) // block
                _add_chunk(n, lag_values, pixels, slots, count, total, total_sq, products, edges, ends, use_ends,
                           cov, var, scratch, head, tail)
    return cov, var


def _edge_inputs(edges: np.ndarray | None, ends: np.ndarray | None,
                 lags: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    if edges is not None:
        return edges, np.zeros((2 * int(lags[-1]), 1), np.uint8), False
    if ends is None or ends.shape[0] != 2 * int(lags[-1]):
        raise ValueError("give the edge sums (L, P) or the window's first and last K frames (2K, P)")
    return np.zeros((lags.size, 1), np.int64), ends, True


def _check_lags(products: np.ndarray, lags: np.ndarray) -> np.ndarray:
    lags = np.ascontiguousarray(lags, np.int64)
    if lags.shape != (products.shape[0],):
        raise ValueError(f"{lags.size} lags for {products.shape[0]} rows of lag products")
    return lags


def pooled_covariances(window: int, total: np.ndarray, total_sq: np.ndarray, products: np.ndarray,
                       edges: np.ndarray | None, ends: np.ndarray | None,
                       pixels: np.ndarray, lags: np.ndarray) -> tuple[np.ndarray, float]:
    """Σ_p cov_p(k) (L,) at ``lags`` and Σ_p var_p over the flat indices ``pixels`` (counts²)."""
    lags = _check_lags(products, lags)
    index = np.ascontiguousarray(pixels, np.int64)
    if numba is None:
        cov_sum, var_sum = np.zeros(lags.size), 0.0
        for start in range(0, index.size, _CHUNK):
            cov, var = _numpy_covariances(window, total, total_sq, products, edges, ends, index[start:start + _CHUNK],
                                          lags)
            cov_sum += cov.sum(axis=1)
            var_sum += float(var.sum())
        return cov_sum, var_sum
    edge_sums, end_frames, use_ends = _edge_inputs(edges, ends, lags)
    parts = max(1, min(numba.get_num_threads(), index.size // 4096))
    cov, var = _pooled_indices(window, lags, index, total, total_sq, products, edge_sums, end_frames, use_ends, parts)
    return cov.sum(axis=1) / _pairs(window, lags), float(var.sum()) / window


def block_covariances(window: int, shape: tuple[int, int], block: int, total: np.ndarray, total_sq: np.ndarray,
                      products: np.ndarray, edges: np.ndarray | None,
                      ends: np.ndarray | None, lags: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pooled cov (L, ceil(H/b), ceil(W/b)) at ``lags`` and var (ceil(H/b), ceil(W/b)) over b×b
    blocks (edge blocks hold what is left of the frame), counts²."""
    if block < 1:
        raise ValueError(f"block must be >= 1, not {block}")
    lags = _check_lags(products, lags)
    rows, cols = -(-shape[0] // block), -(-shape[1] // block)
    if numba is None:
        pooled_cov, pooled_var = np.zeros((lags.size, rows, cols)), np.zeros((rows, cols))
        labels = (np.arange(shape[0])[:, None] // block * cols + np.arange(shape[1])[None, :] // block).ravel()
        for start in range(0, labels.size, _CHUNK):
            index = np.arange(start, min(labels.size, start + _CHUNK))
            cov, var = _numpy_covariances(window, total, total_sq, products, edges, ends, index, lags)
            for j in range(lags.size):
                np.add.at(pooled_cov[j].reshape(-1), labels[index], cov[j])
            np.add.at(pooled_var.reshape(-1), labels[index], var)
        return pooled_cov, pooled_var
    edge_sums, end_frames, use_ends = _edge_inputs(edges, ends, lags)
    cov, var = _pooled_blocks(window, lags, shape[1], block, total, total_sq, products, edge_sums, end_frames, use_ends)
    return cov.reshape(lags.size, rows, cols) / _pairs(window, lags)[:, None, None], var.reshape(rows, cols) / window


def _pairs(window: int, lags: np.ndarray) -> np.ndarray:
    """N - k for each lag k: the pairs each lag's products sum over."""
    return window - lags.astype(np.float64)


def _numpy_covariances(window: int, total: np.ndarray, total_sq: np.ndarray, products: np.ndarray,
                       edges: np.ndarray | None, ends: np.ndarray | None,
                       index: np.ndarray, lags: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel cov (L, len(index)) and var of the pixels ``index`` (numpy path)."""
    if edges is not None:
        edge_sums = edges[:, index].astype(np.int64)
    else:
        _, ends, _ = _edge_inputs(None, ends, lags)
        edge_sums = edges_of(list(ends[:, index]), lags)
    return covariances_from_sums(window, total[index], total_sq[index], products[:, index], edge_sums, lags)
