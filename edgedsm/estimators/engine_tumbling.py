"""The tumbling engine: exact maps of the last completed block of N frames (the paper's §3 sets).

Frames are cut into consecutive blocks [kN, (k+1)N); ``maps()`` returns the maps of the last
*completed* block, equal to the batch reference on that block. Pairs never straddle two blocks.
The S1/S2/S3 sums (:class:`edgedsm.estimators.moment_sums.WindowMoments`) and τc's lag products
and edge sums (:class:`edgedsm.estimators.lag_products.TumblingLagProducts`) of the block in
progress grow by adding only; at a block's end they become the ``done_`` set that ``maps()``
reads, and the others start again from zero. The ring keeps the last m frames (m+1 slots;
K + TAU_BATCH + 1 with τc). With GD (generalized differences) the ring holds whole blocks (its
slots rounded up to a multiple of N, so a block's frames sit in N consecutive rows) and each
frame adds its distance to the block's earlier frames to the exact int64 Σ_{i<j} |I_i - I_j|,
O(N) per pixel per push as in the sliding engine (``kernels.gd_kernel``). With a band map the
block's DFT bins are summed directly (:class:`edgedsm.estimators.dft_bins.DftBins`; its first
frame, the bins' offset, in ``band_origin``). Bounds and memory: docs/engine.md.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from edgedsm.estimators.engine_base import SlidingWindow
from edgedsm.estimators.lag_products import TumblingLagProducts
from edgedsm.estimators.moment_sums import Layout, WindowMoments
from edgedsm.estimators.registry import PAIR_SUM
from edgedsm.estimators.snapshot import TauSnapshot
from edgedsm.frames import sample_dtype

#: The arrays of the last completed block carry this prefix.
DONE = "done_"
#: The block's first frame (the offset of its DFT bins), not part of the completed block's sums.
ORIGIN = "band_origin"


class TumblingEngine(SlidingWindow, mode="tumbling"):
    """:class:`SlidingWindow` with ``mode="tumbling"``."""

    _moments: WindowMoments
    _tau: TumblingLagProducts

    def _accumulators(self) -> tuple[WindowMoments, TumblingLagProducts]:
        keep_totals = self._do_tau or self._bins.on  # ΣI, ΣI² serve τc and the bands' σ²
        return (WindowMoments(self.estimators, self.window, self.lag, self.q, keep_totals=keep_totals),
                TumblingLagProducts(self.window, self.max_lag, self._do_tau))

    def _block_layout(self, bits: int) -> Layout:
        pixels = self.shape[0] * self.shape[1]
        return {**self._moments.layout(pixels, bits), **self._tau.layout(pixels, bits),
                **({PAIR_SUM: ((pixels,), np.int64)} if self._do_gd else {}), **self._bins.layout(pixels, bits)}

    def _layout(self, bits: int) -> Layout:
        pixels = self.shape[0] * self.shape[1]
        block = self._block_layout(bits)
        slots = self._tau.ring_slots(self.lag)
        if self._do_gd:  # whole blocks: block k's frames in rows (kN mod slots) .. + N-1
            slots = -(-slots // self.window) * self.window
        return {"ring": ((slots, pixels), sample_dtype(bits)),
                **block, **{DONE + name: spec for name, spec in block.items()},
                **{name: spec for name, spec in self._bins.layout(pixels, bits, origin=True).items()
                   if name == ORIGIN}}

    def _bind(self, bits: int, parallel: bool) -> None:
        self._moments.bind(self._kernels, self.ratio_kind, self.scale_bits, parallel, slide=False)
        self._tau.bind(self._kernels, parallel, bits)
        if self._do_gd:
            self._gd_step = self._kernels.gd_kernel(False, parallel)
        self._bins.bind(self._kernels, parallel, rotate=False)

    def _frame_reads(self) -> int:
        # the new frame and frame i-m read, a ring slot written; with τc frame i-k for each lag k;
        # with GD the block's earlier frames, (N-1)/2 on average; with the bands the block's first frame
        return 3 + (self.tau_lags.size if self._do_tau else 0) + ((self.window - 1) // 2 if self._do_gd else 0) \
            + (1 if self._bins.on else 0)

    def _sums(self) -> Mapping[str, np.ndarray]:
        """The sums of the last completed block."""
        return {name: self._arrays[DONE + name] for name in self._block_names}

    @property
    def _block_names(self) -> tuple[str, ...]:
        return tuple(name for name in self._arrays if name not in ("ring", ORIGIN) and not name.startswith(DONE))

    def _push(self, new: np.ndarray) -> None:
        i, n, m = self.frames_seen, self.window, self.lag
        position = i % n
        arrays = self._arrays
        ring = arrays["ring"]
        slots = ring.shape[0]
        # frame i goes to slot i % slots, frame i-m is read from another slot
        lagged = ring[(i - m) % slots] if position >= m else new  # no pair across blocks
        self._tau.push(arrays, new, i)
        if self._do_gd:  # the block's frames before this one: rows start .. start+position-1
            start = (i - position) % slots
            self._gd_step(new, ring[start:start + n], 0, position, arrays[PAIR_SUM])
        self._bins.add(arrays, new, position)
        self._moments.add(arrays, new, ring[i % slots], lagged)
        self._tau.after_push(arrays, i)
        if position == n - 1:  # block complete: it becomes the one maps() reports
            for name in self._block_names:
                arrays[name], arrays[DONE + name] = arrays[DONE + name], arrays[name]
                arrays[name].fill(0)
            self.blocks_completed += 1

    def _tau_edges(self, every: Any) -> np.ndarray:
        return self._arrays[DONE + "edges"][:, every]

    def _tau_snapshot_edges(self, old: TauSnapshot | None) -> tuple[np.ndarray | None, np.ndarray | None]:
        source, target = self._arrays[DONE + "edges"], old.edges if old else None
        if target is not None and target.shape == source.shape and target.dtype == source.dtype:
            np.copyto(target, source)
            return target, None
        return source.copy(), None
