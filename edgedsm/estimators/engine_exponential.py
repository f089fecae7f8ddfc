"""The exponential engine: exponentially weighted S1, S2, S3 with a memory of m frames.

Every average is exponentially weighted, weight λ^k for the k-th newest term, λ = 1 - 1/N (so
Σλ^k → N: ``window`` is the equivalent window length); the means are kept in float64 with
normalised (bias-free) updates by :class:`edgedsm.estimators.moment_sums.ExponentialMoments`.
The ring holds the last m frames (frame i-m is read from the slot frame i then takes). No τc:
its bias model is that of a finite window. Definition and bounds: docs/engine.md.
"""

from __future__ import annotations

import numpy as np

from edgedsm.estimators.engine_base import SlidingWindow
from edgedsm.estimators.lag_products import LagProducts
from edgedsm.estimators.moment_sums import ExponentialMoments, Layout
from edgedsm.frames import sample_dtype


class ExponentialEngine(SlidingWindow, mode="exponential"):
    """:class:`SlidingWindow` with ``mode="exponential"``."""

    _moments: ExponentialMoments

    def _accumulators(self) -> tuple[ExponentialMoments, LagProducts]:
        return ExponentialMoments(self.estimators, self.window, self.lag, self.q), LagProducts(self.window, 1, False)

    def _layout(self, bits: int) -> Layout:
        pixels = self.shape[0] * self.shape[1]
        return {"ring": ((self.lag, pixels), sample_dtype(bits)),
                **self._moments.layout(pixels, bits)}

    def _bind(self, bits: int, parallel: bool) -> None:
        self._moments.bind(self._kernels, parallel)

    def _frame_reads(self) -> int:
        return 3  # the new frame and frame i-m read, a ring slot written

    def _push(self, new: np.ndarray) -> None:
        i = self.frames_seen
        self._moments.push(self._arrays, new, self._arrays["ring"][i % self.lag], i >= self.lag)
