"""The τc accumulators of the streaming engine: the lag products, their push kernels, their maps.

Per pixel, Σ I_t·I_{t+k} at the multi-tau lags k of ``tau_lags(K)`` (one row of sums per lag, L
rows; :mod:`edgedsm.estimators.tau_stream` for their types and bounds), next to ΣI and ΣI² that
the S1/S2/S3 accumulator keeps for both (:class:`edgedsm.estimators.moment_sums.WindowMoments`).
The accumulators keep the sums current and hand them to τc's own formulas
(:mod:`edgedsm.estimators.tau_stream`, :mod:`edgedsm.estimators.correlation_time`): covariances,
the per-pixel fit (the map) and the pooled fit of a region (its region reduction).

- :class:`SlidingLagProducts`: each push adds I_i·I_{i-k} and removes I_{i-N}·I_{i-N+k}. When
  the window is long enough (N >= K + TAU_BATCH), the last TAU_BATCH frames that left the ring
  wait in a small buffer (``retired``) and the products of a whole batch are added and removed
  in one pass over the L rows; :meth:`flush` brings them up to date before any τc result.
- :class:`TumblingLagProducts`: products of the block in progress only (no pair straddles two
  blocks), added per batch of TAU_BATCH frames from a ring of K + TAU_BATCH frames, and the
  block's edge sums (its first k and last k frames) accumulated as it goes.

Units: intensity² (counts²) for the products, intensity for the edge sums; lags in frames.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from types import ModuleType
from typing import Any

import numpy as np

from edgedsm.estimators import tau_stream
from edgedsm.estimators.correlation_time import TauC, tau_lags
from edgedsm.frames import sample_dtype

#: Frames whose lag products are added (sliding: and removed) in one pass over the sums.
TAU_BATCH = 16

Layout = dict[str, tuple[tuple[int, ...], Any]]
Kernel = Callable[..., None]


class LagProducts:
    """What both τc accumulators share: the lags, the products' layout and kernel choice.
    ``on``: τc was asked for (otherwise every array has 0 pixels and pushes do nothing)."""

    def __init__(self, window: int, max_lag: int, on: bool) -> None:
        self.window = window
        self.max_lag = max_lag  # K, frames
        self.lags = tau_lags(max_lag)  # the lags the rows of products are kept for (frames)
        self.on = on
        self.pending = 0  # frames whose lag products are not in the sums yet

    def reset(self) -> None:
        self.pending = 0

    def layout(self, pixels: int, bits: int) -> Layout:
        rows = self.lags.size if self.on else 0
        return {"products": ((rows, pixels if rows else 0), tau_stream.product_dtype(self.window, bits))}

    def narrow(self, bits: int) -> bool:
        """The products are int32 (their kernels then vectorise twice as wide)."""
        return np.dtype(tau_stream.product_dtype(self.window, bits)) == np.dtype(np.int32)

    def covariances(self, total: np.ndarray, total_sq: np.ndarray, products: np.ndarray,
                    edges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """cov (L, P) and var (P,) of the window from its exact sums (tau_stream.covariances)."""
        return tau_stream.covariances(self.window, self.max_lag, total, total_sq, products, edges)

    def tau_map(self, shape: tuple[int, int], cov: np.ndarray, var: np.ndarray) -> TauC:
        """Per-pixel τc (frames) and status from every pixel's covariances (tau_stream.tau_map)."""
        return tau_stream.tau_map(self.window, self.max_lag, shape, cov, var)

    def region(self, cov: np.ndarray, var: np.ndarray) -> TauC:
        """A region's τc (frames) from its pixels' pooled covariances (tau_stream.tau_region)."""
        return tau_stream.tau_region(self.window, self.max_lag, cov, var)


class SlidingLagProducts(LagProducts):
    """Lag products of the last N frames (sliding window; ring slot j % N holds frame j)."""

    @property
    def batched(self) -> bool:
        """Products are added in batches when the ring holds every frame a batch needs
        (N >= K + TAU_BATCH)."""
        return self.on and self.window >= self.max_lag + TAU_BATCH

    def layout(self, pixels: int, bits: int) -> Layout:
        layout = super().layout(pixels, bits)
        batch = TAU_BATCH if self.batched else 0  # the last frames that left the ring
        layout["retired"] = ((batch, pixels if batch else 0), sample_dtype(bits))
        return layout

    def bind(self, kernels: ModuleType, parallel: bool, bits: int) -> None:
        narrow = self.narrow(bits)
        self._grow: Kernel = kernels.products_kernel(False, parallel, narrow)
        self._slide: Kernel = kernels.products_kernel(True, parallel, narrow)
        self._batch_slide: Kernel = kernels.batch_slide_kernel(parallel, narrow)

    def push(self, arrays: Mapping[str, np.ndarray], new: np.ndarray, i: int) -> None:
        """Frame i joins (before it is written into the ring: the kernels read the ring only)."""
        if not self.on:
            return
        n, ring, lags = self.window, arrays["ring"], self.lags
        if self.batched and i >= n:  # frame i-N leaves the ring now; its pairs leave with the batch
            arrays["retired"][(i - n) % TAU_BATCH] = ring[i % n]
            self.pending += 1
            return
        lag_slots = (i - lags) % n  # frames i-k
        if i >= n:  # frame i-N (in frame i's slot) and frames i-N+k leave with their pairs
            self._slide(new, ring, i % n, lag_slots, (i - n + lags) % n, arrays["products"], lags.size)
        else:  # the lags k <= i have a frame i-k
            self._grow(new, ring, 0, lag_slots, lag_slots, arrays["products"],
                       int(np.searchsorted(lags, i, side="right")))

    def after_push(self, arrays: Mapping[str, np.ndarray], i: int) -> None:
        """Frame i is in the ring: a full batch is added and removed now."""
        if self.pending == TAU_BATCH:
            self.flush(arrays, i + 1)

    def flush(self, arrays: Mapping[str, np.ndarray], frames_seen: int) -> None:
        """Add and remove the pairs of the pending frames (the last ``pending`` of ``frames_seen``)."""
        if not self.pending:
            return
        n, last = self.window, frames_seen - 1
        frames = np.arange(last - self.pending + 1, last + 1)[:, None]
        steps = self.lags[None, :]
        leaving = frames - n + steps  # frame j-N+k: in the ring unless it already left
        retired = leaving <= last - n
        leave_slots = np.ascontiguousarray(np.where(retired, leaving % TAU_BATCH, leaving % n))
        self._batch_slide(arrays["ring"], arrays["retired"], frames[:, 0] % n, (frames[:, 0] - n) % TAU_BATCH,
                          np.ascontiguousarray((frames - steps) % n), leave_slots, np.ascontiguousarray(retired),
                          arrays["products"])
        self.pending = 0

    def end_slots(self, frames_seen: int) -> np.ndarray:
        """Ring slots of the window's first K and last K frames, in time order."""
        n, lags = self.window, self.max_lag
        return np.array([j % n for j in (*range(frames_seen - n, frames_seen - n + lags),
                                         *range(frames_seen - lags, frames_seen))])

    def edges(self, ring: np.ndarray, frames_seen: int, every: Any) -> np.ndarray:
        """The window's edge sums (L, P) at the pixels ``every``, from its first and last K frames."""
        return tau_stream.edges_of([ring[slot, every] for slot in self.end_slots(frames_seen).tolist()], self.lags)

    def rebuild(self, frames: list[np.ndarray]) -> np.ndarray:
        """The products of the window's ``frames`` (time order), recomputed: (L, P) int64."""
        wide = [frame.astype(np.int64) for frame in frames]
        products = np.zeros((self.lags.size, frames[0].size), np.int64)
        for row, k in enumerate(self.lags.tolist()):
            for j in range(len(wide) - k):
                products[row] += wide[j] * wide[j + k]
        return products


class TumblingLagProducts(LagProducts):
    """Lag products of the block in progress (tumbling window), and its edge sums."""

    def layout(self, pixels: int, bits: int) -> Layout:
        layout = super().layout(pixels, bits)
        rows = self.lags.size if self.on else 0
        layout["edges"] = ((rows, pixels if rows else 0), np.int64)
        return layout

    def ring_slots(self, lag: int) -> int:
        """Ring rows the tumbling engine needs: frame i-m, and the K + TAU_BATCH frames of a batch."""
        return max(lag, self.max_lag + TAU_BATCH if self.on else 0) + 1

    def bind(self, kernels: ModuleType, parallel: bool, bits: int) -> None:
        self._batch: Kernel = kernels.batch_products_kernel(parallel, self.narrow(bits))

    def push(self, arrays: Mapping[str, np.ndarray], new: np.ndarray, i: int) -> None:
        """Frame i joins the edge sums when it is among the block's first k frames (before the
        ring is written)."""
        position = i % self.window
        if self.on and position < self.max_lag:
            arrays["edges"][int(np.searchsorted(self.lags, position, side="right")):] += new

    def after_push(self, arrays: Mapping[str, np.ndarray], i: int) -> None:
        """Frame i is in the ring: a batch (or the block's end) adds the pending products, and
        at the block's end its last k frames join the edge sums."""
        if not self.on:
            return
        position = i % self.window
        self.pending += 1
        ring = arrays["ring"]
        slots = ring.shape[0]
        if self.pending == TAU_BATCH or position == self.window - 1:
            frames = np.arange(i - self.pending + 1, i + 1)
            lag_slots = np.ascontiguousarray((frames[:, None] - self.lags[None, :]) % slots)
            # lags k <= position: no pair across blocks
            lag_counts = np.searchsorted(self.lags, frames % self.window, side="right")
            self._batch(ring, frames % slots, lag_slots, lag_counts, arrays["products"])
            self.pending = 0
        if position == self.window - 1:  # the last k frames of the block, k = 1..K, are in the ring
            tail = np.zeros(ring.shape[1], np.int64)
            row = 0
            for k in range(1, self.max_lag + 1):
                tail += ring[(i - k + 1) % slots]
                if k == self.lags[row]:
                    arrays["edges"][row] += tail
                    row += 1
