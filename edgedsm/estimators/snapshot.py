"""A frozen copy of a streaming engine's sums, and the maps computed from it on another thread.

:meth:`SlidingWindow.snapshot` copies the state the maps depend on (sliding and tumbling: the
integer sums; exponential: the float64 means and M2) — a memory copy, about the cost of one push.
:func:`maps_from` turns that copy into float maps with the engine's own maps kernel compiled
for the calling thread alone (``parallel=False``; the numba kernels release the GIL), so an
evaluator thread computes maps beside the next pushes without touching the engine. The maps
are bit-identical to :meth:`SlidingWindow.maps` at the moment of the snapshot (tested): the
same kernel arithmetic runs on the same integers.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

from edgedsm.estimators import tau_stream
from edgedsm.estimators.correlation_time import tau_lags
from edgedsm.estimators.registry import PAIR_SUM, REGISTRY, VALUES, KernelSpec, load
from edgedsm.estimators.value_set import gd_of_sum


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
    # window modes: abs, ratio, total, total_sq, sq and, with GD, gd; exponential: abs, ratio, mean, m2, sq
    sums: dict[str, np.ndarray]
    weight_frames: float  # exponential mode: Σλ^k over the frames
    maps_step: Callable[..., None]  # the engine's maps kernel for one thread
    value_names: tuple[str, ...]  # the sums activity.pixel_values reads, in its order (moment_sums)
    # with a band map: (sums, names) -> the flat band maps (dft_bins.DftBins.maps), sums with "bins"
    bands: Callable[..., dict[str, np.ndarray]] | None = None

    @property
    def value_inputs(self) -> tuple[np.ndarray, ...]:
        """The sums a pixel's values are formed from, in the order of activity.pixel_values."""
        return tuple(self.sums[name] for name in self.value_names)

    @property
    def nbytes(self) -> int:
        return sum(array.nbytes for array in self.sums.values())


@dataclass
class MapBuffers:
    """Float64 map arrays that :func:`maps_from` writes into again once nobody else holds them.

    Fresh arrays of a large sensor cost more than the maps kernel itself: the kernel's first
    touch of each page faults, several times the kernel's arithmetic at large frames
    (docs/bench-design.md). An array is reused only when the pool's own
    reference is the last one (the maps handed out, their views and whatever a sink kept all
    count), so a sink may keep a map as long as it likes: the pool then allocates a new set.
    Used from one thread.
    """

    sets: int = 2  # sets of arrays kept for reuse (a sink may still hold the previous one)
    _pool: list[dict[str, np.ndarray]] = field(default_factory=list)

    def reserve(self, snapshot: EngineSnapshot) -> None:
        """Pool one set of arrays for :func:`maps_from` of snapshots like this one, written once
        now so that the first maps evaluation faults in no fresh pages."""
        for array in self.take(map_sizes(snapshot)).values():
            array.fill(0.0)

    def take(self, sizes: dict[str, int]) -> dict[str, np.ndarray]:
        """Arrays of these sizes nobody else holds: a pooled set, or a new one (pooled)."""
        for arrays in self._pool:
            if all(arrays.get(name) is not None and arrays[name].size == size for name, size in sizes.items()) \
                    and _unshared(arrays):
                return arrays
        arrays = {name: np.empty(size) for name, size in sizes.items()}
        self._pool = [arrays, *self._pool][: self.sets]
        return arrays


def _unshared(arrays: dict[str, np.ndarray]) -> bool:
    """Only the pool's dict holds each array: CPython's reference count is the dict's and
    getrefcount's own argument; a map handed out (a view) holds one more through its ``base``."""
    return all(sys.getrefcount(arrays[name]) <= 2 for name in arrays)


def derived_maps(names: Iterable[str], values: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The registry's "derived" maps among ``names``, each its ``derive`` function of the fused
    pass's ``values`` it names (flat or (H, W) arrays alike; new arrays)."""
    records = (REGISTRY[name] for name in names if name in REGISTRY)
    return {r.name: load(r.derive)(*(values[i] for i in r.inputs)) for r in records
            if r.source == "derived" and r.derive is not None}


def map_sizes(snapshot: EngineSnapshot) -> dict[str, int]:
    """Pixels of each array the maps kernel writes for this snapshot (0: not computed), in the
    order of :data:`edgedsm.estimators.registry.VALUES`, and GD's map when the snapshot carries it."""
    pixels = snapshot.shape[0] * snapshot.shape[1]
    return {**KernelSpec.of(snapshot.estimators).sizes(pixels),
            **({PAIR_SUM: pixels} if PAIR_SUM in snapshot.estimators else {})}


def maps_from(snapshot: EngineSnapshot, buffers: MapBuffers | None = None) -> dict[str, np.ndarray]:
    """The requested maps of a snapshot as float64 (H, W) arrays (pure; any thread): new arrays,
    or with ``buffers`` arrays of that pool that nobody holds any more."""
    sizes = map_sizes(snapshot)
    flat = buffers.take(sizes) if buffers is not None else {name: np.empty(size) for name, size in sizes.items()}
    if any(sizes[name] for name in VALUES):
        snapshot.maps_step(*snapshot.value_inputs, snapshot.pairs, snapshot.ratio_unit, snapshot.window,
                           *(flat[name] for name in VALUES), snapshot.weight_frames)
    if derived := derived_maps(snapshot.estimators, flat):  # new arrays, as SlidingWindow.maps forms them
        flat = {**flat, **derived}
    if PAIR_SUM in snapshot.estimators:  # from its exact sum, as SlidingWindow.maps forms it
        gd_of_sum(snapshot.sums[PAIR_SUM], snapshot.window, out=flat[PAIR_SUM])
    if snapshot.bands is not None:  # new arrays: the band maps' own formulas (dft_bins)
        flat = {**flat, **snapshot.bands(snapshot.sums, tuple(n for n in snapshot.estimators if n not in flat))}
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
