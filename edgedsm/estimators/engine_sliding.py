"""The sliding engine: exact maps of the last N frames (paper Eq. 1-4), and τc.

The window is the last N frames i-N+1..i; its N-m pairs are (j, j+m). Each push adds the pair
(i-m, i) and the frame i, and removes the pair (i-N, i-N+m) and the frame i-N, in the S1/S2/S3
sums (:class:`edgedsm.estimators.moment_sums.WindowMoments`) and τc's lag products
(:class:`edgedsm.estimators.lag_products.SlidingLagProducts`). The ring holds N frames, not
N+1: slot j % N holds frame j, and the slot of frame i-N is read and overwritten by frame i in
the same pass. With GD (generalized differences) Σ_{i<j} |I_i - I_j| over the window is kept
exactly: frame i adds its distance to the window's other frames and frame i-N takes its own
away, O(N) per pixel per push (``kernels.gd_kernel``). With a band map the kept DFT bins follow
the sliding DFT, and 1/N of the pixels are re-anchored from the ring at each push
(:class:`edgedsm.estimators.dft_bins.DftBins`). Bounds and memory: docs/engine.md.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from edgedsm.estimators.engine_base import SlidingWindow
from edgedsm.estimators.lag_products import SlidingLagProducts
from edgedsm.estimators.moment_sums import Layout, WindowMoments
from edgedsm.estimators.registry import PAIR_SUM
from edgedsm.estimators.snapshot import TauSnapshot
from edgedsm.frames import sample_dtype


class SlidingEngine(SlidingWindow, mode="sliding"):
    """:class:`SlidingWindow` with ``mode="sliding"``."""

    _moments: WindowMoments
    _tau: SlidingLagProducts

    def _accumulators(self) -> tuple[WindowMoments, SlidingLagProducts]:
        keep_totals = self._do_tau or self._bins.on  # ΣI, ΣI² serve τc and the bands' σ²
        return (WindowMoments(self.estimators, self.window, self.lag, self.q, keep_totals=keep_totals),
                SlidingLagProducts(self.window, self.max_lag, self._do_tau))

    def _layout(self, bits: int) -> Layout:
        pixels = self.shape[0] * self.shape[1]
        return {"ring": ((self.window, pixels), sample_dtype(bits)),
                **self._moments.layout(pixels, bits), **self._tau.layout(pixels, bits),
                **({PAIR_SUM: ((pixels,), np.int64)} if self._do_gd else {}), **self._bins.layout(pixels, bits)}

    def _bind(self, bits: int, parallel: bool) -> None:
        self._moments.bind(self._kernels, self.ratio_kind, self.scale_bits, parallel, slide=True)
        self._tau.bind(self._kernels, parallel, bits)
        if self._do_gd:
            self._gd_steps = (self._kernels.gd_kernel(False, parallel), self._kernels.gd_kernel(True, parallel))
        self._bins.bind(self._kernels, parallel, rotate=True)

    def _frame_reads(self) -> int:
        # the new frame and frame i-m read, a ring slot written, frames i-N (from the slot it
        # overwrites) and i-N+m read; with τc frames i-k and i-N+k for each lag k; with GD the
        # window's N frames; with the bands, the N frames of 1/N of the pixels (the re-anchor)
        return 5 + (2 * self.tau_lags.size if self._do_tau else 0) + (self.window if self._do_gd else 0) \
            + (1 if self._bins.on else 0)

    def _push(self, new: np.ndarray) -> None:
        i, n, m = self.frames_seen, self.window, self.lag
        arrays = self._arrays
        ring = arrays["ring"]
        slot = ring[i % n]  # slot j % N holds frame j: frame i replaces frame i-N
        # no pair before frame m: pairing the frame with itself adds |x-x| = 0 exactly
        lagged = ring[(i - m) % n] if i >= m else new
        self._tau.push(arrays, new, i)  # reads the ring only: before frame i is written
        if self._do_gd:  # frames 0..i-1 in slots 0..i-1 while the window fills, then all but slot i % N
            grow, slide = self._gd_steps
            (slide if i >= n else grow)(new, ring, i % n, min(i, n), arrays[PAIR_SUM])
        # frame i-N leaves the bins; while the window fills, frame 0 stands for the frames before it
        self._bins.slide(arrays, new, slot if i >= n else ring[0] if i else new)
        if i >= n:  # slot holds frame i-N: the kernel reads it, then writes frame i there
            self._moments.slide(arrays, new, slot, lagged, ring[(i - n + m) % n])
        else:
            self._moments.add(arrays, new, slot, lagged)
        self._tau.after_push(arrays, i)
        self._bins.reanchor(arrays, ring, i + 1)  # the bins of 1/N of the pixels, exact again

    def _flush(self) -> None:
        self._tau.flush(self._arrays, self.frames_seen)

    def _tau_edges(self, every: Any) -> np.ndarray:
        return self._tau.edges(self._arrays["ring"], self.frames_seen, every)

    def _tau_snapshot_edges(self, old: TauSnapshot | None) -> tuple[np.ndarray | None, np.ndarray | None]:
        # the window's first K and last K frames, in time order: the edge sums are formed from
        # them off the pipeline thread (snapshot.tau_covariances)
        ring, slots = self._arrays["ring"], self._tau.end_slots(self.frames_seen)
        target = old.ends if old and old.ends is not None and old.ends.shape[0] == slots.size \
            and old.ends.dtype == ring.dtype else None
        return None, np.take(ring, slots, axis=0, out=target) if target is not None else np.take(ring, slots, axis=0)

    def resync(self) -> None:
        """Recompute every sum from the frames in the ring (O(N) per pixel).

        The running sums are exact, so this reproduces them bit for bit; it exists to
        repair state damaged from outside (bad memory) in runs of months.
        """
        if self.frames_seen == 0:
            return
        n = self.window
        ring = self._arrays["ring"]
        frames = [ring[j % n] for j in range(max(0, self.frames_seen - n), self.frames_seen)]
        fresh = {name: np.zeros_like(array) for name, array in self._arrays.items() if name != "ring"}
        self._moments.rebuild(fresh, frames, self.lag)
        if self._do_gd:  # Σ_{i<j} |x_i - x_j| = Σ_k (2k - n + 1) x_(k) for the sorted values
            ordered = np.sort(np.stack(frames), axis=0)
            for k, values in enumerate(ordered):
                fresh[PAIR_SUM] += (2 * k - len(frames) + 1) * values.astype(np.int64)
        self._bins.reanchor(fresh, ring, self.frames_seen, slice(None))
        if self._do_tau:
            fresh["products"][:] = self._tau.rebuild(frames)
            fresh["retired"][:] = self._arrays["retired"]
            self._tau.pending = 0  # the rebuilt sums hold every frame of the window
        self._arrays.update(fresh)
