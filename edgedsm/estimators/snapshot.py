"""A frozen copy of a streaming engine's sums, and the maps computed from it on another thread.

:meth:`SlidingWindow.snapshot` copies the state the maps depend on (sliding and tumbling: the
integer sums; exponential: the float64 means) — a memory copy, about the cost of one push.
:func:`maps_from` turns that copy into float maps with the engine's own maps kernel compiled
for the calling thread alone (``parallel=False``; the numba kernels release the GIL), so an
evaluator thread computes maps beside the next pushes without touching the engine. The maps
are bit-identical to :meth:`SlidingWindow.maps` at the moment of the snapshot (tested): the
same kernel arithmetic runs on the same integers.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from edgedsm.estimators import tau_stream
from edgedsm.estimators.correlation_time import tau_lags


@dataclass(frozen=True)
class EngineSnapshot:
    """The sums of one window at one moment (arrays owned by the snapshot, flat)."""

    shape: tuple[int, int]
    mode: str
    estimators: tuple[str, ...]
    window: int
    pairs: int
    ratio_unit: float  # 2^-K, the S2 fixed-point unit (window modes)
    frames_seen: int
    sums: dict[str, np.ndarray]  # window modes: abs, ratio, total, total_sq; exponential: abs, ratio, m2
    weight_frames: float  # exponential mode: Σλ^k over the frames
    maps_step: Callable[..., None]  # the engine's maps kernel for one thread (window modes)

    @property
    def nbytes(self) -> int:
        return sum(array.nbytes for array in self.sums.values())


def maps_from(snapshot: EngineSnapshot) -> dict[str, np.ndarray]:
    """The requested maps of a snapshot as new float64 (H, W) arrays (pure; any thread)."""
    sums = snapshot.sums
    n_px = snapshot.shape[0] * snapshot.shape[1]
    wanted = set(snapshot.estimators)
    if snapshot.mode == "exponential":
        flat: dict[str, np.ndarray] = {}
        if "s1" in wanted or "s3" in wanted:
            flat["s1"] = sums["abs"]
        if "s2" in wanted:
            flat["s2"] = sums["ratio"]
        if "s3" in wanted:
            sigma = np.sqrt(sums["m2"] / snapshot.weight_frames)
            flat["s3"] = np.zeros_like(flat["s1"])
            np.divide(flat["s1"], sigma, out=flat["s3"], where=sigma > 0)
    else:
        do_abs = "s1" in wanted or "s3" in wanted
        do_ratio, do_sigma = "s2" in wanted, "s3" in wanted
        flat = {name: np.empty(n_px if on else 0) for name, on in
                (("s1", do_abs), ("s2", do_ratio), ("s3", do_sigma), ("sigma", do_sigma))}
        snapshot.maps_step(sums["abs"], sums["ratio"], sums["total"], sums["total_sq"], snapshot.pairs,
                           snapshot.ratio_unit, snapshot.window, flat["s1"], flat["s2"], flat["s3"], flat["sigma"])
    return {name: flat[name].reshape(snapshot.shape) for name in snapshot.estimators}


@dataclass(frozen=True)
class TauSnapshot:
    """The integer sums τc of one window is formed from, at one moment (copies; see
    :meth:`SlidingWindow.tau_snapshot`): ΣI and ΣI² (P,), the lag products Σ_t I_t·I_{t+k}
    (L, P) at the lags k of ``tau_lags(max_lag)`` (:attr:`lags`), and either the edge sums
    (L, P) (tumbling: accumulated during the block) or the
    first K and last K frames of the window in time order (2K, P) (sliding: the edge sums are
    formed from them by :func:`tau_covariances`, off the pipeline thread)."""

    shape: tuple[int, int]
    window: int
    max_lag: int
    frames_seen: int
    total: np.ndarray
    total_sq: np.ndarray
    products: np.ndarray
    edges: np.ndarray | None
    ends: np.ndarray | None

    @property
    def lags(self) -> np.ndarray:
        """The lags (frames) of the rows of ``products`` and ``edges``."""
        return tau_lags(self.max_lag)

    @property
    def nbytes(self) -> int:
        arrays = (self.total, self.total_sq, self.products, self.edges, self.ends)
        return sum(array.nbytes for array in arrays if array is not None)


def tau_covariances(snapshot: TauSnapshot, pixels: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """cov (L, P) and var (P,) of the snapshot's window for all pixels or the flat indices
    ``pixels`` (pure; any thread): the same integers and float64 steps as
    :meth:`SlidingWindow.region_tau_c` and ``maps()["tau_c"]``, so the same τc."""
    every = slice(None) if pixels is None else pixels
    if snapshot.edges is not None:
        edges = snapshot.edges[:, every]
    else:
        assert snapshot.ends is not None
        edges = tau_stream.edges_of(list(snapshot.ends[:, every]), snapshot.lags)
    return tau_stream.covariances(snapshot.window, snapshot.max_lag, snapshot.total[every], snapshot.total_sq[every],
                                  snapshot.products[:, every], edges)
