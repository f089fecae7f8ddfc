"""What every mode of the streaming engine shares: arguments, frame validation, and the public API.

:class:`SlidingWindow` is the engine's one public class. Constructing it picks the engine of its
``mode`` (a subclass: :mod:`edgedsm.estimators.engine_sliding`, ``engine_tumbling``,
``engine_exponential``, registered by :mod:`edgedsm.estimators.streaming`), which keeps a ring of
frames and feeds them to its accumulators, one per descriptor family: the S1/S2/S3 sums
(:mod:`edgedsm.estimators.moment_sums`), τc's lag products (:mod:`edgedsm.estimators.lag_products`)
and the frequency bands' DFT bins (:mod:`edgedsm.estimators.dft_bins`). This class holds what
does not depend on the mode: maps, snapshots, τc results and memory accounting, after the
checks of its arguments and frames (:mod:`edgedsm.estimators.engine_checks`). A mode engine
provides ``_layout`` (its arrays), ``_bind`` (its kernels), ``_push`` (one frame) and
``_sums`` (the sums ``maps()`` reads). Modes, bounds and memory: docs/engine.md.
"""

from __future__ import annotations

import functools
import importlib
import inspect
import math
from collections.abc import Iterable, Mapping, Sequence
from types import ModuleType
from typing import Any, ClassVar, Literal

import numpy as np

from edgedsm.errors import EstimatorError
from edgedsm.estimators import tau_stream
from edgedsm.estimators.correlation_time import TauC, _check_mask, tau_lags
from edgedsm.estimators.dft_bins import BAND_NAMES, DftBins, band_plan
from edgedsm.estimators.engine_checks import (
    BANDS,
    check_estimators,
    check_frame,
    check_int,
    check_maps,
    check_q,
    check_shape,
)
from edgedsm.estimators.fixed_point import ratio_kind, ratio_scale_bits, s2_error_bound
from edgedsm.estimators.lag_products import LagProducts
from edgedsm.estimators.moment_sums import Layout, Moments
from edgedsm.estimators.registry import PAIR_SUM, KernelSpec, get
from edgedsm.estimators.snapshot import EngineSnapshot, TauSnapshot, derived_maps
from edgedsm.estimators.value_set import gd_of_sum
from edgedsm.frames import sample_dtype

Mode = Literal["sliding", "exponential", "tumbling"]
KernelName = Literal["auto", "numba", "numpy"]

MODES: tuple[str, ...] = ("sliding", "exponential", "tumbling")
KERNELS: tuple[str, ...] = ("auto", "numba", "numpy")
DEFAULT_ESTIMATORS: tuple[str, ...] = ("s1", "s2", "s3")  # τc costs O(lags) per pixel: only when asked
MAX_WINDOW = 2**31 - 1  # ΣI² of 16-bit data stays below 2^63
PARALLEL_MIN_PIXELS = 1 << 16  # smaller frames run on the calling thread (numba kernel)


def load_kernels(kernel: str) -> ModuleType:
    """The kernel module: numba when asked for or, with "auto", when it can be imported."""
    fallback = "edgedsm.estimators.kernels_numpy"
    if kernel == "numpy":
        return importlib.import_module(fallback)
    try:
        return importlib.import_module("edgedsm.estimators.kernels_numba")
    except ImportError as exc:
        if kernel == "numba":
            raise EstimatorError(
                "kernel='numba' needs numba (install the 'fast' extra: pip install 'edgedsm[fast]')"
                f"; import failed: {exc}") from exc
        return importlib.import_module(fallback)


class SlidingWindow:
    """Streaming S1/S2/S3 maps (Eq. 1-4) and τc over a window of N frames at lag m.

    Args:
        shape: (height, width) of the frames in pixels.
        window: N, frames per window (``exponential``: equivalent length, λ = 1 - 1/N).
        lag: m, the time lag in frames, 1 <= m <= N-1.
        q: the constant of Eq. 2 (grey levels, >= 0) that keeps 0/0 away.
        bits: bit depth of the data (1..16); None infers it from the first frame's dtype
            (uint8 -> 8, uint16 -> 16). Values above 2^bits - 1 are refused.
        estimators: the maps ``maps()`` returns (default S1, S2, S3), any streamed map of
            :mod:`edgedsm.estimators.registry` (its record gives the modes it needs, q = 0 for Fujii,
            its cost per push; only their sums are kept), or "bands": the power in each of
            ``bands``, one (K, H, W) map (not in snapshots).
        mode: "sliding" (default), "exponential" or "tumbling" (docs/engine.md); the engine
            constructed is that mode's subclass.
        kernel: "numba" (parallel, fused), "numpy" (fallback) or "auto" (numba if installed).
        threads: numba worker threads (None: numba's default); the numpy kernel ignores it,
            and so do frames under PARALLEL_MIN_PIXELS (65 536) pixels, run on one thread.
        resync_every: sliding mode only: recompute the sums from the ring every this many
            frames (None: never; the sums are exact, this only guards against bad memory).
        max_lag: K, the longest lag of "tau_c" (None: N/2); 1 <= K <= N-2. τc is
            fitted at the multi-tau lags ``tau_lags(K)`` (1, 2, 3, 4, 6, 8, 11, 15, 20 for
            K = 20), one row of lag products each. "tau_c" needs mode "sliding" or "tumbling"
            (its bias model is that of a finite window).
        dt: the frame interval in seconds, the bands' frequency scale (None: cycles per frame).
        band_split: the bands' split frequency, Hz with ``dt`` (else cycles per frame), below
            the Nyquist frequency; None: half of it.
        bands: "bands"' frequency bands (lo, hi], Hz with ``dt`` (else cycles per frame).

    Exactness, bounds, memory per pixel and the degenerate cases: docs/engine.md.
    """

    mode: ClassVar[str] = ""
    _engines: ClassVar[dict[str, type[SlidingWindow]]] = {}
    _moments: Moments
    _tau: LagProducts

    def __init_subclass__(cls, mode: str = "", **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if mode:
            cls.mode = mode
            SlidingWindow._engines[mode] = cls

    def __new__(cls, *args: Any, **kwargs: Any) -> SlidingWindow:
        if cls is SlidingWindow:  # the engine of the mode asked for (7th argument)
            mode = kwargs.get("mode", args[6] if len(args) > 6 else None)
            mode = "sliding" if mode is None else mode
            if not isinstance(mode, str) or mode not in SlidingWindow._engines:
                raise EstimatorError(f"mode must be one of {', '.join(MODES)}; got {mode!r}")
            cls = SlidingWindow._engines[mode]
        return super().__new__(cls)

    def __init__(self, shape: tuple[int, int], window: int, lag: int, q: float = 0.0,
                 bits: int | None = None, estimators: Iterable[str] | str = DEFAULT_ESTIMATORS,
                 mode: Mode | None = None, kernel: KernelName = "auto",
                 threads: int | None = None, resync_every: int | None = None,
                 max_lag: int | None = None, dt: float | None = None, band_split: float | None = None,
                 bands: Sequence[tuple[float, float]] | None = None) -> None:
        if mode is not None and mode != self.mode:
            raise EstimatorError(f"mode {mode!r} asked of the {self.mode} engine")
        self.shape = check_shape(shape)
        self.window = check_int("window N", window, 2, MAX_WINDOW)
        self.lag = check_int("lag m", lag, 1, self.window - 1)
        self.q = check_q(q)
        self.estimators = check_estimators(estimators)
        check_maps(self.estimators, self.mode, self.q, self.window)  # the registry's statements: modes, q
        self._do_gd = any(get(name).source == "pair_sum" for name in self.estimators if name != BANDS)
        self._bins = DftBins(self.window, band_plan(self.estimators, self.mode, self.window, dt, band_split, bands))
        if kernel not in KERNELS:
            raise EstimatorError(f"kernel must be one of {', '.join(KERNELS)}; got {kernel!r}")
        self._kernels = load_kernels(kernel)
        self.kernel: str = self._kernels.KERNEL
        if threads is not None:
            # numba cannot start more workers than it was configured with; numpy ignores it
            most = self._kernels.max_threads() if self.kernel == "numba" else 1 << 16
            threads = check_int("threads", threads, 1, most)
        self.threads = threads
        if resync_every is not None:
            if self.mode != "sliding":
                raise EstimatorError("resync_every needs mode='sliding' (only it keeps the window)")
            resync_every = check_int("resync_every", resync_every, 1, 2**62)
        self.resync_every = resync_every
        self._bits_given = None if bits is None else check_int("bits", bits, 1, 16)
        self.pairs = self.window - self.lag  # N - m pairs per window (Eq. 1-3)
        self.ratio_kind = ""  # how S2 terms are formed, and K: known with the bit depth
        self.scale_bits = 0
        self._do_tau = any(get(name).source == "tau" for name in self.estimators if name != BANDS)
        self.max_lag = tau_stream.max_lag_of(self.window, max_lag)
        self.tau_lags = tau_lags(self.max_lag)  # the lags τc keeps products for (frames)
        if self._do_tau and self.window < 3:
            raise EstimatorError("estimator 'tau_c' needs a window of at least 3 frames (K < N-1)")
        self._moments, self._tau = self._accumulators()
        self.bits: int | None = None
        self._arrays: dict[str, np.ndarray] = {}
        self._parallel = False
        self.reset()

    # ----------------------------------------------------------------- the mode engine's part
    def _accumulators(self) -> tuple[Moments, LagProducts]:
        """The S1/S2/S3 and the τc accumulator of this mode."""
        raise NotImplementedError

    def _layout(self, bits: int) -> Layout:
        """Name -> (shape, dtype) of every state array; sums of maps not asked for get 0 pixels."""
        raise NotImplementedError

    def _bind(self, bits: int, parallel: bool) -> None:
        """Pick the compiled kernels for ``bits``-bit data (the arrays are allocated)."""
        raise NotImplementedError

    def _push(self, new: np.ndarray) -> None:
        """Frame ``frames_seen`` (flat) into the ring and the sums."""
        raise NotImplementedError

    def _sums(self) -> Mapping[str, np.ndarray]:
        """The sums ``maps()`` and snapshots read (by name)."""
        return self._arrays

    def _frame_reads(self) -> int:
        """Frame-sized arrays one push reads or writes (the new frame, ring slots)."""
        raise NotImplementedError

    def _flush(self) -> None:
        """Bring the lag products up to date (a batch in progress is added)."""

    def _tau_edges(self, every: Any) -> np.ndarray:
        """The window's τc edge sums (L, P) at the pixels ``every`` (after ``_flush``)."""
        raise NotImplementedError

    def resync(self) -> None:
        """Sliding mode: recompute every sum from the frames in the ring (see engine_sliding)."""
        raise EstimatorError("resync() needs mode='sliding': other modes keep no window")

    # ----------------------------------------------------------------- validation
    def _check_ready(self) -> None:
        if not self.ready:
            raise EstimatorError(f"the window is not full yet: {self.frames_seen} of "
                                 f"{self.window} frames pushed (check .ready)")

    # ----------------------------------------------------------------- state
    def _allocate(self, bits: int) -> None:
        self.bits = bits
        self._arrays = {name: np.zeros(shape, dtype) for name, (shape, dtype) in self._layout(bits).items()}
        self.ratio_kind = ratio_kind(bits, self.q)
        self.scale_bits = ratio_scale_bits(self.pairs, self.ratio_kind)
        # small frames: waking worker threads would cost more than the whole pass
        parallel = self.shape[0] * self.shape[1] >= PARALLEL_MIN_PIXELS
        self._parallel = parallel and self.kernel == "numba"
        self._bind(bits, parallel)

    def reset(self) -> None:
        """Forget every frame (a bit depth inferred from a frame is forgotten too). With the bit
        depth given, the arrays are kept and zeroed in place (:meth:`fault_in`): fresh arrays
        would fault their pages in again during the next filling, at the frames' pace."""
        self.frames_seen = 0
        self.blocks_completed = 0  # tumbling mode
        self._moments.reset()
        self._tau.reset()
        if self._bits_given is not None and self._arrays:
            self.fault_in()
            return
        self.bits = None
        self._arrays = {}
        if self._bits_given is not None:
            self._allocate(self._bits_given)

    def fault_in(self) -> None:
        """Write every page of the engine's arrays now (zeros; the window must be empty). A
        fresh array's pages fault in at their first write: during the window's filling, one
        ring slot and all the sums at the first push, paid by the frames' thread; at large
        frames on a virtual machine whose host backs memory lazily, seconds (docs/bench-e2e.md).
        The daemon calls this before frames flow."""
        if self.frames_seen:
            raise EstimatorError(f"fault_in() would erase the {self.frames_seen} frames pushed: reset() first")
        for array in self._arrays.values():
            array.fill(0)

    def array_bytes(self) -> dict[str, int]:
        """Bytes of each array the engine keeps (the ring, each sum), as allocated for its frames'
        bit depth (empty before the first frame when no ``bits`` was given)."""
        return {name: array.nbytes for name, array in self._arrays.items()}

    @property
    def ready(self) -> bool:
        """True once N frames were pushed: ``maps()`` describes a whole window."""
        return self.frames_seen >= self.window

    @property
    def bytes_per_pixel(self) -> float:
        """Memory of the engine's state per pixel, bytes (the shared S2 table excluded;
        before the bit depth is known, for 8-bit data)."""
        bits = self.bits if self.bits is not None else 8
        total = sum(math.prod(shape) * np.dtype(dtype).itemsize for shape, dtype in self._layout(bits).values())
        return total / (self.shape[0] * self.shape[1])

    @property
    def traffic_per_pixel(self) -> float:
        """Bytes one push must move per pixel: frame and ring slots read/written, sums read
        and written once (the memory-bandwidth model of ``edgedsm bench engine``)."""
        bits = self.bits if self.bits is not None else 8
        n_px = self.shape[0] * self.shape[1]
        sums = {**self._moments.layout(n_px, bits), "products": self._tau.layout(n_px, bits)["products"],
                **{name: value for name, value in self._layout(bits).items() if name in (PAIR_SUM, "bins")}}
        moved = sum(math.prod(shape) * np.dtype(dtype).itemsize for shape, dtype in sums.values())
        return self._frame_reads() * sample_dtype(bits).itemsize + 2 * moved / n_px

    @property
    def s2_bound(self) -> float:
        """Absolute bound on |S2 - exact S2| in sliding/tumbling mode (docs/engine.md);
        before the bit depth is known, the bound for 16-bit data."""
        return s2_error_bound(self.pairs, self.bits if self.bits is not None else 16, self.q)

    # ----------------------------------------------------------------- streaming
    def push(self, frame: np.ndarray) -> None:
        """Take the next frame (2-D, the engine's shape and dtype); O(1) work per pixel."""
        bits = check_frame(frame, self.shape, self.bits)
        if self.bits is None:
            self._allocate(bits)
        if self._parallel:
            # numba's thread count is a per-thread global: set it for every call, so that
            # another engine's setting never leaks into this one
            self._kernels.set_threads(self.threads)
        self._push(frame.reshape(-1))
        self.frames_seen += 1
        if self.resync_every is not None and self.frames_seen % self.resync_every == 0:
            self.resync()

    # ----------------------------------------------------------------- maps
    def maps(self, names: Iterable[str] | None = None) -> dict[str, np.ndarray]:
        """The requested maps (``names``: some of them; a τc map costs a fit per pixel) of the
        current window as new float64 (H, W) arrays: sliding, the last N frames; tumbling, the
        last completed block; exponential, the weighted estimates (docs/engine.md). Raises
        EstimatorError before N frames were pushed."""
        wanted = self.estimators if names is None else tuple(names)
        if unknown := sorted(set(wanted) - set(self.estimators)):
            raise EstimatorError(f"maps {unknown} were not requested from this engine (it has {self.estimators})")
        self._check_ready()
        sources = {name: "bins" if name == BANDS else get(name).source for name in wanted}
        fused = KernelSpec.of(name for name in wanted if name != BANDS).any
        flat = self._moments.maps(self._sums(), self.shape[0] * self.shape[1]) if fused else {}
        flat.update(derived_maps(wanted, flat))
        if PAIR_SUM in wanted:
            flat[PAIR_SUM] = gd_of_sum(self._sums()[PAIR_SUM], self.window)
        if bands := tuple(name for name in wanted if sources[name] == "bins"):
            flat.update(self._bins.maps(self._sums(), bands, self.q))
        return {name: self.tau_c_bounds().tau if sources[name] == "tau" else
                flat[name].reshape((*flat[name].shape[:-1], *self.shape)) for name in wanted}

    def sigma(self) -> np.ndarray:
        """σ of Eq. 4 over the current window (grey levels), float64 (H, W); needs "s3"."""
        if "s3" not in self.estimators:
            raise EstimatorError("sigma() needs 's3' among the estimators")
        self._check_ready()
        return self._moments.maps(self._sums(), self.shape[0] * self.shape[1])["sigma"].reshape(self.shape)

    # ----------------------------------------------------------------- τc
    def _tau_covariances(self, pixels: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """cov (L, P) and var (P,) of the current window from the exact sums, for all pixels or
        the flat indices ``pixels`` (a region costs its own size only)."""
        if not self._do_tau:
            raise EstimatorError("τc needs 'tau_c' among the estimators")
        self._check_ready()
        self._flush()
        sums, every = self._sums(), slice(None) if pixels is None else pixels
        return self._tau.covariances(sums["total"][every], sums["total_sq"][every], sums["products"][:, every],
                                     self._tau_edges(every))

    def tau_c_bounds(self) -> TauC:
        """Per-pixel τc (frames) and status of the current window, equal to
        :func:`edgedsm.estimators.tau_c_bounds` on it with ``max_lag`` K."""
        return self._tau.tau_map(self.shape, *self._tau_covariances())

    def region_tau_c(self, mask: np.ndarray) -> TauC:
        """A region's τc (frames) and status from its pooled correlations (boolean (H, W)
        ``mask``), equal to ``tau_c_bounds(window, K, mask=mask)``; costs O(K) per pixel of
        the region."""
        region = _check_mask(mask, self.shape)
        return self._tau.region(*self._tau_covariances(np.flatnonzero(region)))

    def tau_snapshot(self, into: TauSnapshot | None = None) -> TauSnapshot:
        """Copies of the integer sums τc is formed from (needs "tau_c"): about L+4 sums of
        memory traffic per pixel; :func:`edgedsm.estimators.snapshot.tau_covariances` turns them
        into the covariances ``region_tau_c`` and ``maps()["tau_c"]`` fit, on any thread.
        ``into``: an older snapshot nobody reads any more, whose arrays are overwritten."""
        if not self._do_tau:
            raise EstimatorError("tau_snapshot() needs 'tau_c' among the estimators")
        self._check_ready()
        self._flush()
        sums, lags = self._sums(), self.max_lag
        old = into if into is not None and into.shape == self.shape and into.max_lag == lags else None
        edges, ends = self._tau_snapshot_edges(old)
        return TauSnapshot(shape=self.shape, window=self.window, max_lag=lags, frames_seen=self.frames_seen,
                           total=_copy(sums["total"], old.total if old else None),
                           total_sq=_copy(sums["total_sq"], old.total_sq if old else None),
                           products=_copy(sums["products"], old.products if old else None),
                           edges=edges, ends=ends)

    def _tau_snapshot_edges(self, old: TauSnapshot | None) -> tuple[np.ndarray | None, np.ndarray | None]:
        """(edge sums, None) or (None, the window's first and last K frames) for a τc snapshot."""
        raise NotImplementedError

    # ----------------------------------------------------------------- snapshots
    def snapshot(self, estimators: Iterable[str] | None = None, into: EngineSnapshot | None = None,
                 live: bool = False) -> EngineSnapshot:
        """Copies of the sums ``maps()`` reads for ``estimators`` (default: the engine's own),
        about half a push of memory traffic; :func:`edgedsm.estimators.snapshot.maps_from` turns
        them into the same maps, on any thread. ``into``: an older snapshot nobody reads any
        more, whose arrays are overwritten (no fresh pages to fault in: about half the cost).
        ``live``: views of the engine's own sums, no copy, valid until the next push or reset
        (read them on the thread that pushes, e.g. with
        :func:`edgedsm.estimators.region_stats.region_moments`)."""
        self._check_ready()
        return self._snapshot_of(estimators, into, "live" if live else "copy")

    def snapshot_buffers(self, estimators: Iterable[str] | None = None) -> EngineSnapshot:
        """Arrays for a later ``snapshot(into=...)``, allocated and written once now (zeros, not
        a snapshot: any time, full window or not). Fresh pages fault in at the first write, and
        at large frames the first copy into new arrays stalls the pushing thread ten times as
        long as a copy into these (docs/bench-design.md); take them before frames flow."""
        return self._snapshot_of(estimators, None, "zeros")

    def _snapshot_of(self, estimators: Iterable[str] | None, into: EngineSnapshot | None,
                     how: str) -> EngineSnapshot:
        if estimators is not None and BANDS in estimators:
            raise EstimatorError(f"a snapshot does not carry {BANDS!r} (maps() gives it)")
        wanted = tuple(name for name in self.estimators if name != BANDS) if estimators is None \
            else check_estimators(estimators)
        if not set(wanted) <= set(self.estimators):
            raise EstimatorError(f"the engine keeps the sums of {', '.join(self.estimators)} only, not {wanted}")
        spec = KernelSpec.of(wanted)
        bands = bool(set(wanted) & set(BAND_NAMES))
        spread = spec.sigma or bands  # S3, the contrast and the bands need σ
        needed = {"abs": spec.s1, "ratio": spec.s2, "total": spread, "total_sq": spread, "m2": spread,
                  "mean": spec.contrast, "sq": spec.im, PAIR_SUM: PAIR_SUM in wanted, "bins": bands}
        source_sums, old = self._sums(), into.sums if into is not None else {}
        sums = {}
        for name in (*self._moments.snapshot_names, *((PAIR_SUM,) if self._do_gd else ()),
                     *(("bins",) if self._bins.on else ())):
            source = source_sums.get(name)
            if not needed[name] or source is None:
                sums[name] = np.zeros(0, np.int64)
            elif how == "live":
                sums[name] = source
            elif how == "zeros":
                sums[name] = np.full_like(source, 0)  # written: np.zeros' pages would fault in later
            else:
                sums[name] = _copy(source, old.get(name))
        return EngineSnapshot(
            shape=self.shape, mode=self.mode, estimators=wanted, window=self.window,
            pairs=self.pairs, ratio_unit=2.0**-self.scale_bits, frames_seen=self.frames_seen,
            sums=sums, weight_frames=self._moments.weight_frames,
            maps_step=self._moments.maps_step(self._kernels, spec), value_names=self._moments.value_names,
            bands=functools.partial(self._bins.maps, q=self.q) if bands else None)

    def _snapshot(self) -> dict[str, Any]:
        """Copies of the whole state (for tests and debugging), lag products brought up to date."""
        self._flush()
        state: dict[str, Any] = {name: array.copy() for name, array in self._arrays.items()}
        state.update(frames_seen=self.frames_seen, bits=self.bits, blocks_completed=self.blocks_completed,
                     weights=self._moments.weights)
        return state

    def __repr__(self) -> str:
        return (f"SlidingWindow(shape={self.shape}, window={self.window}, lag={self.lag}, "
                f"q={self.q}, bits={self.bits}, estimators={self.estimators}, "
                f"mode={self.mode!r}, kernel={self.kernel!r}, frames_seen={self.frames_seen})")


# help() and notebooks show the constructor's parameters, not __new__'s (*args, **kwargs), which
# only picks the engine of the mode asked for
SlidingWindow.__signature__ = inspect.Signature(  # type: ignore[attr-defined]
    list(inspect.signature(SlidingWindow.__init__).parameters.values())[1:])


def _copy(source: np.ndarray, target: np.ndarray | None) -> np.ndarray:
    """``source`` copied into ``target`` when it has the same shape and dtype, else a new copy."""
    if target is not None and target.shape == source.shape and target.dtype == source.dtype:
        np.copyto(target, source)
        return target
    return source.copy()
