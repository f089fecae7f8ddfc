"""Streaming estimator engine: S1, S2, S3 (paper Eq. 1-4), τc, and the field's temporal contrast,
Fujii and inertia moment (docs/descriptors.md) at O(1) cost per pixel per frame.

:class:`SlidingWindow` takes frames one at a time (``push``) and returns the activity maps of
its window on demand (``maps``). Intensities are grey levels (integers, ``bits`` per pixel);
S1 is in grey levels, S2 and S3 are dimensionless, τc is in frames; the window N and the lag m
are in frames.

Modes: ``sliding`` (exact: the last N frames), ``tumbling`` (exact: the last completed block of
N frames, the paper's §3 sets) and ``exponential`` (weights λ^k, λ = 1 - 1/N, memory of m
frames). S1 and σ are exact integer sums, bit-identical to the batch reference for ever; S2 is
an exact sum of fixed-point terms with a stated bound (:mod:`edgedsm.estimators.fixed_point`);
τc uses exact integer lag products (:mod:`edgedsm.estimators.tau_stream`). Modes, memory per
pixel, every bound and its proof: ``docs/engine.md``.

How it is built (docs/engine.md, "Structure"): ``SlidingWindow(..., mode=...)`` constructs the
engine of its mode (:mod:`edgedsm.estimators.engine_sliding`, ``engine_tumbling``,
``engine_exponential``; the shared part in :mod:`edgedsm.estimators.engine_base`), each over the
accumulators of the descriptor families: S1/S2/S3 (:mod:`edgedsm.estimators.moment_sums`), τc
(:mod:`edgedsm.estimators.lag_products`) and the frequency bands
(:mod:`edgedsm.estimators.dft_bins`). A pixel's values from the sums are written once, in
:mod:`edgedsm.estimators.activity`. Importing this module registers the three modes.

Degenerate cases are those of the batch reference: a pair with a+b+q = 0 contributes 0 to
S2; S3 = 0 where σ = 0 (constant or saturated pixel). Maps never contain NaN or inf.

Frames are validated before anything changes: 2-D numpy array of the engine's shape,
dtype uint8 (bits <= 8) or uint16 (9..16 bits) in native byte order, C-contiguous, no value
above 2^bits - 1. A refused frame raises :class:`~edgedsm.errors.FrameError` and leaves the
engine untouched.
"""

from __future__ import annotations

from edgedsm.estimators.engine_base import KERNELS, MODES, PARALLEL_MIN_PIXELS, SlidingWindow
from edgedsm.estimators.engine_exponential import ExponentialEngine
from edgedsm.estimators.engine_sliding import SlidingEngine
from edgedsm.estimators.engine_tumbling import TumblingEngine
from edgedsm.estimators.fixed_point import ratio_kind, ratio_lut, ratio_scale_bits, s2_error_bound
from edgedsm.estimators.lag_products import TAU_BATCH

#: The engine of each mode (each registered itself with SlidingWindow when its module was imported).
ENGINES = {"sliding": SlidingEngine, "tumbling": TumblingEngine, "exponential": ExponentialEngine}

__all__ = ["ENGINES", "KERNELS", "MODES", "PARALLEL_MIN_PIXELS", "TAU_BATCH", "SlidingWindow", "ratio_kind",
           "ratio_lut", "ratio_scale_bits", "s2_error_bound"]
