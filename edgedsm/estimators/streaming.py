"""Streaming estimator engine: S1, S2, S3 (paper Eq. 1-4) and τc at O(1) cost per pixel per frame.

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

Degenerate cases are those of the batch reference: a pair with a+b+q = 0 contributes 0 to
S2; S3 = 0 where σ = 0 (constant or saturated pixel). Maps never contain NaN or inf.

Frames are validated before anything changes: 2-D numpy array of the engine's shape,
dtype uint8 (bits <= 8) or uint16 (9..16 bits) in native byte order, C-contiguous, no value
above 2^bits - 1. A refused frame raises :class:`~edgedsm.errors.FrameError` and leaves the
engine untouched.
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Iterable
from types import ModuleType
from typing import Any, Literal

import numpy as np

from edgedsm.errors import EstimatorError, FrameError
from edgedsm.estimators import tau_stream
from edgedsm.estimators.correlation_time import TauC, _check_mask, default_max_lag, tau_lags, tau_mode_problem
from edgedsm.estimators.fixed_point import _NO_LUT, ratio_kind, ratio_lut, ratio_scale_bits, s2_error_bound
from edgedsm.estimators.snapshot import EngineSnapshot, TauSnapshot

__all__ = ["KERNELS", "MODES", "PARALLEL_MIN_PIXELS", "SlidingWindow", "ratio_kind", "ratio_lut",
           "ratio_scale_bits", "s2_error_bound"]

Mode = Literal["sliding", "exponential", "tumbling"]
KernelName = Literal["auto", "numba", "numpy"]

MODES: tuple[str, ...] = ("sliding", "exponential", "tumbling")
KERNELS: tuple[str, ...] = ("auto", "numba", "numpy")
_ESTIMATORS: tuple[str, ...] = ("s1", "s2", "s3", "tau_c")
_DEFAULT_ESTIMATORS: tuple[str, ...] = ("s1", "s2", "s3")  # τc costs O(lags) per pixel: only when asked
_MAX_WINDOW = 2**31 - 1  # ΣI² of 16-bit data stays below 2^63
_INT32_MAX = 2**31 - 1
PARALLEL_MIN_PIXELS = 1 << 16  # smaller frames run on the calling thread (numba kernel)
TAU_BATCH = 16  # τc: frames whose lag products are added (sliding: and removed) in one pass over the sums


def _load_kernels(kernel: str) -> ModuleType:
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


def _sum_dtype(largest: int) -> type[np.signedinteger[Any]]:
    """int32 when the largest value a sum can reach fits, else int64 (less memory traffic)."""
    return np.int32 if largest <= _INT32_MAX else np.int64


def _check_int(name: str, value: Any, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise EstimatorError(f"{name} must be an integer, got {value!r}")
    if not low <= value <= high:
        raise EstimatorError(f"{name} must be in [{low}, {high}], got {value}")
    return int(value)


class SlidingWindow:
    """Streaming S1/S2/S3 maps (Eq. 1-4) over a window of N frames at lag m.

    Args:
        shape: (height, width) of the frames in pixels.
        window: N, frames per window (``exponential``: equivalent length, λ = 1 - 1/N).
        lag: m, the time lag in frames, 1 <= m <= N-1.
        q: the constant of Eq. 2 (grey levels, >= 0) that keeps 0/0 away.
        bits: bit depth of the data (1..16); None infers it from the first frame's dtype
            (uint8 -> 8, uint16 -> 16). Values above 2^bits - 1 are refused.
        estimators: which of "s1", "s2", "s3", "tau_c" ``maps()`` returns (default: the first
            three); only their sums are kept.
        mode: "sliding", "exponential" or "tumbling" (see the module docstring).
        kernel: "numba" (parallel, fused), "numpy" (fallback) or "auto" (numba if installed).
        threads: numba worker threads (None: numba's default); the numpy kernel ignores it,
            and so do frames under PARALLEL_MIN_PIXELS (65 536) pixels, run on one thread.
        resync_every: sliding mode only: recompute the sums from the ring every this many
            frames (None: never; the sums are exact, this only guards against bad memory).
        max_lag: K, the longest lag of "tau_c" (None: min(2m, N-2)); 1 <= K <= N-2. τc is
            fitted at the multi-tau lags ``tau_lags(K)`` (1, 2, 3, 4, 6, 8, 11, 15, 20 for
            K = 20), one row of lag products each. "tau_c" needs mode "sliding" or "tumbling"
            (its bias model is that of a finite window).

    Exactness, bounds, memory per pixel and the degenerate cases: see the module docstring.
    """

    def __init__(self, shape: tuple[int, int], window: int, lag: int, q: float = 0.0,
                 bits: int | None = None, estimators: Iterable[str] | str = _DEFAULT_ESTIMATORS,
                 mode: Mode = "sliding", kernel: KernelName = "auto",
                 threads: int | None = None, resync_every: int | None = None,
                 max_lag: int | None = None) -> None:
        self.shape = self._check_shape(shape)
        self.window = _check_int("window N", window, 2, _MAX_WINDOW)
        self.lag = _check_int("lag m", lag, 1, self.window - 1)
        if isinstance(q, bool) or not isinstance(q, int | float | np.integer | np.floating):
            raise EstimatorError(f"q must be a number, got {q!r}")
        if not (math.isfinite(q) and q >= 0):
            raise EstimatorError(f"q must be a finite number >= 0, got {q}")
        self.q = float(q)
        self.estimators = self._check_estimators(estimators)
        if mode not in MODES:
            raise EstimatorError(f"mode must be one of {', '.join(MODES)}; got {mode!r}")
        self.mode: str = mode
        if kernel not in KERNELS:
            raise EstimatorError(f"kernel must be one of {', '.join(KERNELS)}; got {kernel!r}")
        self._kernels = _load_kernels(kernel)
        self.kernel: str = self._kernels.KERNEL
        if threads is not None:
            # numba cannot start more workers than it was configured with; numpy ignores it
            most = self._kernels.max_threads() if self.kernel == "numba" else 1 << 16
            threads = _check_int("threads", threads, 1, most)
        self.threads = threads
        if resync_every is not None:
            if mode != "sliding":
                raise EstimatorError("resync_every needs mode='sliding' (only it keeps the window)")
            resync_every = _check_int("resync_every", resync_every, 1, 2**62)
        self.resync_every = resync_every
        self._bits_given = None if bits is None else _check_int("bits", bits, 1, 16)
        self.pairs = self.window - self.lag  # N - m pairs per window (Eq. 1-3)
        self.ratio_kind = ""  # how S2 terms are formed, and K: known with the bit depth
        self.scale_bits = 0
        self._do_abs = "s1" in self.estimators or "s3" in self.estimators
        self._do_ratio = "s2" in self.estimators
        self._do_sigma = "s3" in self.estimators
        self._do_tau = "tau_c" in self.estimators
        self._do_sums = self._do_sigma or self._do_tau  # ΣI and ΣI² serve S3 and τc
        if self._do_tau and (problem := tau_mode_problem(mode)):
            raise EstimatorError(f"estimator 'tau_c': {problem}")
        default_lag = default_max_lag(self.window, self.lag)
        self.max_lag = default_lag if max_lag is None else _check_int("max_lag K", max_lag, 1,
                                                                      max(1, self.window - 2))
        self.tau_lags = tau_lags(self.max_lag)  # the lags τc keeps products for (frames)
        if self._do_tau and self.window < 3:
            raise EstimatorError("estimator 'tau_c' needs a window of at least 3 frames (K < N-1)")
        self.bits: int | None = None
        self._arrays: dict[str, np.ndarray] = {}
        self._parallel = False
        self.reset()

    # ----------------------------------------------------------------- validation
    @staticmethod
    def _check_shape(shape: Any) -> tuple[int, int]:
        try:
            dims = tuple(shape)
        except TypeError:
            raise EstimatorError(f"shape must be (height, width), got {shape!r}") from None
        if len(dims) != 2:
            raise EstimatorError(f"shape must be (height, width), got {shape!r}")
        return (_check_int("height", dims[0], 1, 2**31), _check_int("width", dims[1], 1, 2**31))

    @staticmethod
    def _check_estimators(estimators: Iterable[str] | str) -> tuple[str, ...]:
        names = (estimators,) if isinstance(estimators, str) else tuple(estimators)
        unknown = [name for name in names if name not in _ESTIMATORS]
        if unknown or not names:
            raise EstimatorError(
                f"estimators must be a non-empty subset of {_ESTIMATORS}, got {estimators!r}")
        return tuple(name for name in _ESTIMATORS if name in names)

    def _check_frame(self, frame: Any) -> int:
        """Validate one frame (nothing is changed); returns its bit depth."""
        if not isinstance(frame, np.ndarray):
            raise FrameError(f"a frame must be a numpy array, got {type(frame).__name__}")
        if frame.shape != self.shape:
            raise FrameError(f"frame shape {frame.shape} does not match the engine's {self.shape}")
        if self.bits is not None:
            bits = self.bits
            expected = np.dtype(np.uint8 if bits <= 8 else np.uint16)
            if frame.dtype != expected:
                raise FrameError(f"frame dtype {frame.dtype} is not {expected} "
                                 f"(the engine takes {bits}-bit data)")
        elif frame.dtype == np.dtype(np.uint8):
            bits = 8
        elif frame.dtype == np.dtype(np.uint16):
            bits = 16
        else:
            raise FrameError(f"frame dtype {frame.dtype} is not uint8 or uint16 "
                             "(native byte order)")
        if not frame.flags.c_contiguous:
            raise FrameError("frame is not C-contiguous (pass np.ascontiguousarray(frame))")
        if bits < 8 * frame.dtype.itemsize:
            top = int(frame.max())
            if top > (1 << bits) - 1:
                raise FrameError(f"frame value {top} is above the {bits}-bit range "
                                 f"0..{(1 << bits) - 1}")
        return bits

    # ----------------------------------------------------------------- state
    def _layout(self, bits: int) -> dict[str, tuple[tuple[int, ...], Any]]:
        """Name -> (shape, dtype) of every state array; requested-off sums get 0 pixels."""
        n_px = self.shape[0] * self.shape[1]
        top = (1 << bits) - 1
        frame_dtype = np.uint8 if bits <= 8 else np.uint16
        n, m = self.window, self.lag
        if self.mode == "exponential":
            return {
                "ring": ((m, n_px), frame_dtype),
                "mean": ((n_px if self._do_sigma else 0,), np.float64),
                "m2": ((n_px if self._do_sigma else 0,), np.float64),
                "abs": ((n_px if self._do_abs else 0,), np.float64),
                "ratio": ((n_px if self._do_ratio else 0,), np.float64),
            }
        lags = self.tau_lags.size if self._do_tau else 0  # rows of lag products
        longest = self.max_lag if self._do_tau else 0
        sums = {
            "abs": ((n_px if self._do_abs else 0,), _sum_dtype(self.pairs * top)),
            "ratio": ((n_px if self._do_ratio else 0,), np.int64),
            "total": ((n_px if self._do_sums else 0,), _sum_dtype(n * top)),
            "total_sq": ((n_px if self._do_sums else 0,), _sum_dtype(n * top * top)),
            "products": ((lags, n_px if lags else 0), tau_stream.product_dtype(n, bits)),
        }
        if self.mode == "tumbling":  # first-k sums of the block in progress, last-k added at its end
            sums["edges"] = ((lags, n_px if lags else 0), np.int64)
        batched = self.mode == "sliding" and lags and self._sliding_batch()
        # sliding τc: the last TAU_BATCH frames that left the ring (their pairs leave in a batch)
        sums["retired"] = ((TAU_BATCH if batched else 0, n_px if batched else 0), frame_dtype)
        layout: dict[str, tuple[tuple[int, ...], Any]] = {
            "ring": ((n if self.mode == "sliding" else max(m, longest + TAU_BATCH if lags else 0) + 1, n_px),
                     frame_dtype)}
        layout.update(sums)
        if self.mode == "tumbling":
            layout.update({f"done_{name}": spec for name, spec in sums.items()})
        return layout

    def _allocate(self, bits: int) -> None:
        self.bits = bits
        self._arrays = {name: np.zeros(shape, dtype)
                        for name, (shape, dtype) in self._layout(bits).items()}
        kind = self.ratio_kind = ratio_kind(bits, self.q)
        self.scale_bits = ratio_scale_bits(self.pairs, kind)
        use_lut = kind == "lut" and self._do_ratio and self.mode != "exponential"
        self._lut = ratio_lut(self.q, self.scale_bits) if use_lut else _NO_LUT
        flags = (self._do_abs, self._do_ratio, self._do_sigma)
        sum_flags = (self._do_abs, self._do_ratio, self._do_sums)
        kernels = self._kernels
        # small frames: waking worker threads would cost more than the whole pass
        parallel = self.shape[0] * self.shape[1] >= PARALLEL_MIN_PIXELS
        self._parallel = parallel and self.kernel == "numba"
        self._maps_step = kernels.maps_kernel(*flags, parallel, self.mode == "exponential")
        if self.mode == "exponential":
            self._step_exp = kernels.exponential_kernel(*flags, parallel)
        else:
            # "grow": add only (tumbling, and sliding until N frames are in); "slide": add+remove
            self._step_grow = kernels.window_kernel(*sum_flags, kind, False, parallel)
            narrow = np.dtype(self._layout(bits)["products"][1]) == np.dtype(np.int32)
            self._products_grow = kernels.products_kernel(False, parallel, narrow)
            self._products_batch = kernels.batch_products_kernel(parallel, narrow)
            self._products_batch_slide = kernels.batch_slide_kernel(parallel, narrow)
            if self.mode == "sliding":
                self._step_slide = kernels.window_kernel(*sum_flags, kind, True, parallel)
                self._products_slide = kernels.products_kernel(True, parallel, narrow)
                self._step_pairs = kernels.pairs_kernel(self._do_abs, self._do_ratio, kind,
                                                        parallel)

    def reset(self) -> None:
        """Forget every frame (a bit depth inferred from a frame is forgotten too)."""
        self.frames_seen = 0
        self.blocks_completed = 0  # tumbling mode
        self._weight_frames = 0.0  # exponential mode: Σλ^k over frames and over pairs
        self._weight_pairs = 0.0
        self._pending = 0  # tumbling τc: frames in the ring whose lag products are not added yet
        self.bits = None
        self._arrays = {}
        if self._bits_given is not None:
            self._allocate(self._bits_given)

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
        total = 0
        for shape, dtype in self._layout(bits).values():
            total += math.prod(shape) * np.dtype(dtype).itemsize
        return total / (self.shape[0] * self.shape[1])

    @property
    def traffic_per_pixel(self) -> float:
        """Bytes one push must move per pixel: frame and ring slots read/written, sums read
        and written once (the memory-bandwidth model of ``edgedsm bench engine``)."""
        bits = self.bits if self.bits is not None else 8
        frame_bytes = 1 if bits <= 8 else 2
        layout = self._layout(bits)
        n_px = self.shape[0] * self.shape[1]
        # new frame and frame i-m read, a ring slot written; sliding also reads frames i-N
        # (from the slot it overwrites) and i-N+m
        frames = (5 if self.mode == "sliding" else 3) * frame_bytes
        if self._do_tau:  # frames i-k and, sliding, i-N+k for each lag k
            frames += (2 if self.mode == "sliding" else 1) * self.tau_lags.size * frame_bytes
        sums = sum(math.prod(shape) * np.dtype(dtype).itemsize for name, (shape, dtype)
                   in layout.items() if name not in ("ring", "edges", "retired") and not name.startswith("done_"))
        return frames + 2 * sums / n_px

    @property
    def s2_bound(self) -> float:
        """Absolute bound on |S2 - exact S2| in sliding/tumbling mode (see module docstring);
        before the bit depth is known, the bound for 16-bit data."""
        return s2_error_bound(self.pairs, self.bits if self.bits is not None else 16, self.q)

    # ----------------------------------------------------------------- streaming
    def push(self, frame: np.ndarray) -> None:
        """Take the next frame (2-D, the engine's shape and dtype); O(1) work per pixel."""
        bits = self._check_frame(frame)
        if self.bits is None:
            self._allocate(bits)
        if self._parallel:
            # numba's thread count is a per-thread global: set it for every call, so that
            # another engine's setting never leaks into this one
            self._kernels.set_threads(self.threads)
        new = frame.reshape(-1)
        if self.mode == "sliding":
            self._push_sliding(new)
        elif self.mode == "tumbling":
            self._push_tumbling(new)
        else:
            self._push_exponential(new)
        self.frames_seen += 1
        if self.resync_every is not None and self.frames_seen % self.resync_every == 0:
            self.resync()

    def _window_step(self, step: Any, new: np.ndarray, slot: np.ndarray, lagged: np.ndarray,
                     leaving: np.ndarray) -> None:
        arrays = self._arrays
        step(new, slot, lagged, leaving, arrays["abs"], arrays["ratio"], arrays["total"],
             arrays["total_sq"], self._lut, float(2**self.scale_bits), self.q)

    def _push_sliding(self, new: np.ndarray) -> None:
        i, n, m = self.frames_seen, self.window, self.lag
        ring = self._arrays["ring"]
        slot = ring[i % n]  # slot j % N holds frame j: frame i replaces frame i-N
        # no pair before frame m: pairing the frame with itself adds |x-x| = 0 exactly
        lagged = ring[(i - m) % n] if i >= m else new
        batched = self._do_tau and i >= n and self._sliding_batch()
        if batched:  # frame i-N leaves the ring now; its pairs leave with the next batch
            self._arrays["retired"][(i - n) % TAU_BATCH] = ring[i % n]
        elif self._do_tau:  # reads the ring only: before the window kernel writes frame i
            steps = self.tau_lags
            lag_slots = (i - steps) % n  # frames i-k
            if i >= n:  # frame i-N (in frame i's slot) and frames i-N+k leave with their pairs
                self._products_slide(new, ring, i % n, lag_slots, (i - n + steps) % n,
                                     self._arrays["products"], steps.size)
            else:  # the lags k <= i have a frame i-k
                self._products_grow(new, ring, 0, lag_slots, lag_slots, self._arrays["products"],
                                    int(np.searchsorted(steps, i, side="right")))
        if i >= n:  # slot holds frame i-N: the kernel reads it, then writes frame i there
            self._window_step(self._step_slide, new, slot, lagged, ring[(i - n + m) % n])
        else:
            self._window_step(self._step_grow, new, slot, lagged, lagged)
        if batched:
            self._pending += 1
            if self._pending == TAU_BATCH:
                self._flush_sliding(i)

    def _sliding_batch(self) -> bool:
        """Sliding τc adds lag products in batches when the ring holds every frame a batch
        needs (N >= K + TAU_BATCH)."""
        return self.window >= self.max_lag + TAU_BATCH

    def _flush_sliding(self, last: int) -> None:
        """Sliding τc: add and remove the pairs of the pending frames last-pending+1..last."""
        n = self.window
        frames = np.arange(last - self._pending + 1, last + 1)[:, None]
        steps = self.tau_lags[None, :]
        leaving = frames - n + steps  # frame j-N+k: in the ring unless it already left
        retired = leaving <= last - n
        leave_slots = np.ascontiguousarray(np.where(retired, leaving % TAU_BATCH, leaving % n))
        self._products_batch_slide(self._arrays["ring"], self._arrays["retired"], frames[:, 0] % n,
                                   (frames[:, 0] - n) % TAU_BATCH, np.ascontiguousarray((frames - steps) % n),
                                   leave_slots, np.ascontiguousarray(retired), self._arrays["products"])
        self._pending = 0

    def _flush(self) -> None:
        """Bring the lag products up to date (pending batched frames added)."""
        if self._pending and self.mode == "sliding":
            self._flush_sliding(self.frames_seen - 1)

    def _push_tumbling(self, new: np.ndarray) -> None:
        i, n, m = self.frames_seen, self.window, self.lag
        position = i % n
        ring = self._arrays["ring"]
        slots = ring.shape[0]
        # max(m, K + TAU_BATCH)+1 slots (m+1 without τc): frame i goes to slot i % slots, frame i-m is
        # read from another slot
        slot = ring[i % slots]
        lagged = ring[(i - m) % slots] if position >= m else new  # no pair across blocks
        arrays = self._arrays
        if self._do_tau and position < self.max_lag:  # frame i is among the first k frames, k > position
            arrays["edges"][int(np.searchsorted(self.tau_lags, position, side="right")):] += new
        self._window_step(self._step_grow, new, slot, lagged, lagged)
        if self._do_tau:
            self._pending += 1
            if self._pending == TAU_BATCH or position == n - 1:
                self._flush_products(i)
        if position == n - 1:  # block complete: it becomes the one maps() reports
            if self._do_tau:  # the last k frames of the block, k = 1..K, are in the ring
                tail = np.zeros(new.size, np.int64)
                row = 0
                for k in range(1, self.max_lag + 1):
                    tail += ring[(i - k + 1) % slots]
                    if k == self.tau_lags[row]:
                        arrays["edges"][row] += tail
                        row += 1
            for name in ("abs", "ratio", "total", "total_sq", "products", "edges"):
                arrays[name], arrays["done_" + name] = arrays["done_" + name], arrays[name]
                arrays[name].fill(0)
            self.blocks_completed += 1

    def _flush_products(self, last: int) -> None:
        """Tumbling τc: add the lag products of the pending frames last-pending+1..last (all in
        the ring, which keeps K + TAU_BATCH frames) in one pass over the sums."""
        slots, n = self._arrays["ring"].shape[0], self.window
        frames = np.arange(last - self._pending + 1, last + 1)
        steps = self.tau_lags
        lag_slots = np.ascontiguousarray((frames[:, None] - steps[None, :]) % slots)
        lag_counts = np.searchsorted(steps, frames % n, side="right")  # lags k <= position: no pair across blocks
        self._products_batch(self._arrays["ring"], frames % slots, lag_slots, lag_counts,
                             self._arrays["products"])
        self._pending = 0

    def _push_exponential(self, new: np.ndarray) -> None:
        i, m = self.frames_seen, self.lag
        decay = 1.0 - 1.0 / self.window  # λ
        add_pair = i >= m
        self._weight_frames = decay * self._weight_frames + 1.0
        if add_pair:
            self._weight_pairs = decay * self._weight_pairs + 1.0
        arrays = self._arrays
        # before frame m there is no pair: weight 0 leaves the pair means unchanged
        self._step_exp(new, arrays["ring"][i % m], arrays["mean"], arrays["m2"], arrays["abs"],
                       arrays["ratio"], decay, 1.0 / self._weight_frames,
                       1.0 / self._weight_pairs if add_pair else 0.0, self.q)

    def resync(self) -> None:
        """Sliding mode: recompute every sum from the frames in the ring (O(N) per pixel).

        The running sums are exact, so this reproduces them bit for bit; it exists to
        repair state damaged from outside (bad memory) in runs of months.
        """
        if self.mode != "sliding":
            raise EstimatorError("resync() needs mode='sliding': other modes keep no window")
        if self.frames_seen == 0:
            return
        n, m = self.window, self.lag
        ring = self._arrays["ring"]
        first = max(0, self.frames_seen - n)
        frames = [ring[j % n] for j in range(first, self.frames_seen)]
        fresh = {name: np.zeros_like(array) for name, array in self._arrays.items()
                 if name != "ring"}
        if self._do_sums:
            total = np.zeros(frames[0].size, np.int64)
            total_sq = np.zeros(frames[0].size, np.int64)
            for frame in frames:
                wide = frame.astype(np.int64)
                total += wide
                total_sq += wide * wide
            fresh["total"][:] = total
            fresh["total_sq"][:] = total_sq
        for j in range(len(frames) - m):
            self._step_pairs(frames[j], frames[j + m], fresh["abs"], fresh["ratio"],
                             self._lut, float(2**self.scale_bits), self.q)
        if self._do_tau:
            wide = [frame.astype(np.int64) for frame in frames]
            products = np.zeros((self.tau_lags.size, frames[0].size), np.int64)
            for row, k in enumerate(self.tau_lags.tolist()):
                for j in range(len(wide) - k):
                    products[row] += wide[j] * wide[j + k]
            fresh["products"][:] = products
            fresh["retired"][:] = self._arrays["retired"]
            self._pending = 0  # the rebuilt sums hold every frame of the window
        self._arrays.update(fresh)

    # ----------------------------------------------------------------- maps
    def maps(self, names: Iterable[str] | None = None) -> dict[str, np.ndarray]:
        """The requested maps (``names``: some of them; a τc map costs a fit per pixel) of the
        current window as new float64 (H, W) arrays: sliding, the last N frames; tumbling, the
        last completed block; exponential, the weighted estimates (module docstring). Raises
        EstimatorError before N frames were pushed."""
        wanted = self.estimators if names is None else tuple(names)
        if unknown := sorted(set(wanted) - set(self.estimators)):
            raise EstimatorError(f"maps {unknown} were not requested from this engine (it has {self.estimators})")
        if not self.ready:
            raise EstimatorError(f"the window is not full yet: {self.frames_seen} of "
                                 f"{self.window} frames pushed (check .ready)")
        only_tau = set(wanted) <= {"tau_c"}
        flat = {} if only_tau else self._window_maps("" if self.mode != "tumbling" else "done_")
        return {name: self.tau_c_bounds().tau if name == "tau_c" else flat[name].reshape(self.shape)
                for name in wanted}

    # ----------------------------------------------------------------- τc
    def _tau_covariances(self, pixels: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """cov (L, P) and var (P,) of the current window from the exact sums, for all pixels or
        the flat indices ``pixels`` (a region costs its own size only)."""
        if not self._do_tau:
            raise EstimatorError("τc needs 'tau_c' among the estimators")
        if not self.ready:
            raise EstimatorError(f"the window is not full yet: {self.frames_seen} of "
                                 f"{self.window} frames pushed (check .ready)")
        self._flush()
        arrays, n, lags = self._arrays, self.window, self.max_lag
        every = slice(None) if pixels is None else pixels
        if self.mode == "tumbling":
            prefix = "done_"
            edges = arrays["done_edges"][:, every]
        else:
            prefix = ""
            ring, seen = arrays["ring"], self.frames_seen
            ends = [ring[j % n, every] for j in range(seen - n, seen - n + lags)]
            ends += [ring[j % n, every] for j in range(seen - lags, seen)]
            edges = tau_stream.edges_of(ends, self.tau_lags)
        return tau_stream.covariances(n, lags, arrays[prefix + "total"][every], arrays[prefix + "total_sq"][every],
                                      arrays[prefix + "products"][:, every], edges)

    def tau_c_bounds(self) -> TauC:
        """Per-pixel τc (frames) and status of the current window, equal to
        :func:`edgedsm.estimators.tau_c_bounds` on it with ``max_lag`` K."""
        cov, var = self._tau_covariances()
        return tau_stream.tau_map(self.window, self.max_lag, self.shape, cov, var)

    def region_tau_c(self, mask: np.ndarray) -> TauC:
        """A region's τc (frames) and status from its pooled correlations (boolean (H, W)
        ``mask``), equal to ``tau_c_bounds(window, K, mask=mask)``; costs O(K) per pixel of
        the region."""
        region = _check_mask(mask, self.shape)
        cov, var = self._tau_covariances(np.flatnonzero(region))
        return tau_stream.tau_region(self.window, self.max_lag, cov, var)

    def snapshot(self, estimators: Iterable[str] | None = None, into: EngineSnapshot | None = None,
                 live: bool = False) -> EngineSnapshot:
        """Copies of the sums ``maps()`` reads for ``estimators`` (default: the engine's own),
        about half a push of memory traffic; :func:`edgedsm.estimators.snapshot.maps_from` turns
        them into the same maps, on any thread. ``into``: an older snapshot nobody reads any
        more, whose arrays are overwritten (no fresh pages to fault in: about half the cost).
        ``live``: views of the engine's own sums, no copy, valid until the next push or reset
        (read them on the thread that pushes, e.g. with
        :func:`edgedsm.estimators.region_stats.region_moments`)."""
        if not self.ready:
            raise EstimatorError(f"the window is not full yet: {self.frames_seen} of "
                                 f"{self.window} frames pushed (check .ready)")
        return self._snapshot_of(estimators, into, "live" if live else "copy")

    def snapshot_buffers(self, estimators: Iterable[str] | None = None) -> EngineSnapshot:
        """Arrays for a later ``snapshot(into=...)``, allocated and written once now (zeros, not
        a snapshot: any time, full window or not). Fresh pages fault in at the first write, and
        at large frames the first copy into new arrays stalls the pushing thread ten times as
        long as a copy into these (docs/bench-design.md); take them before frames flow."""
        return self._snapshot_of(estimators, None, "zeros")

    def _snapshot_of(self, estimators: Iterable[str] | None, into: EngineSnapshot | None,
                     how: str) -> EngineSnapshot:
        wanted = self.estimators if estimators is None else self._check_estimators(estimators)
        if not set(wanted) <= set(self.estimators):
            raise EstimatorError(f"the engine keeps the sums of {', '.join(self.estimators)} only, not {wanted}")
        flags = ("s1" in wanted or "s3" in wanted, "s2" in wanted, "s3" in wanted)
        needed = {"abs": flags[0], "ratio": flags[1], "total": flags[2], "total_sq": flags[2], "m2": flags[2]}
        prefix = "done_" if self.mode == "tumbling" else ""
        names = ("abs", "ratio", "m2") if self.mode == "exponential" else ("abs", "ratio", "total", "total_sq")
        empty = np.zeros(0, np.int64)
        old = into.sums if into is not None else {}
        sums = {}
        for name in names:
            source = self._arrays[prefix + name]
            target = old.get(name)
            if not needed[name]:
                sums[name] = empty
            elif how == "live":
                sums[name] = source
            elif how == "zeros":
                sums[name] = np.full_like(source, 0)  # written: np.zeros' pages would fault in later
            elif target is not None and target.shape == source.shape and target.dtype == source.dtype:
                np.copyto(target, source)
                sums[name] = target
            else:
                sums[name] = source.copy()
        return EngineSnapshot(
            shape=self.shape, mode=self.mode, estimators=wanted, window=self.window,
            pairs=self.pairs, ratio_unit=2.0**-self.scale_bits, frames_seen=self.frames_seen,
            sums=sums,
            weight_frames=self._weight_frames,
            maps_step=self._kernels.maps_kernel(*flags, False, self.mode == "exponential"))

    def tau_snapshot(self, into: TauSnapshot | None = None) -> TauSnapshot:
        """Copies of the integer sums τc is formed from (needs "tau_c"): about L+4 sums of
        memory traffic per pixel; :func:`edgedsm.estimators.snapshot.tau_covariances` turns them
        into the covariances ``region_tau_c`` and ``maps()["tau_c"]`` fit, on any thread.
        ``into``: an older snapshot nobody reads any more, whose arrays are overwritten."""
        if not self._do_tau:
            raise EstimatorError("tau_snapshot() needs 'tau_c' among the estimators")
        if not self.ready:
            raise EstimatorError(f"the window is not full yet: {self.frames_seen} of "
                                 f"{self.window} frames pushed (check .ready)")
        self._flush()
        arrays, n, lags, seen = self._arrays, self.window, self.max_lag, self.frames_seen
        prefix = "done_" if self.mode == "tumbling" else ""

        def copy(source: np.ndarray, target: np.ndarray | None) -> np.ndarray:
            if target is not None and target.shape == source.shape and target.dtype == source.dtype:
                np.copyto(target, source)
                return target
            return source.copy()

        old = into if into is not None and into.shape == self.shape and into.max_lag == lags else None
        edges = ends = None
        if self.mode == "tumbling":
            edges = copy(arrays["done_edges"], old.edges if old else None)
        else:  # the window's first K and last K frames, in time order (slot j % N holds frame j)
            slots = np.array([j % n for j in (*range(seen - n, seen - n + lags), *range(seen - lags, seen))])
            target = old.ends if old and old.ends is not None and old.ends.shape[0] == slots.size else None
            ends = np.take(arrays["ring"], slots, axis=0, out=target) if target is not None and \
                target.dtype == arrays["ring"].dtype else np.take(arrays["ring"], slots, axis=0)
        return TauSnapshot(shape=self.shape, window=n, max_lag=lags, frames_seen=seen,
                           total=copy(arrays[prefix + "total"], old.total if old else None),
                           total_sq=copy(arrays[prefix + "total_sq"], old.total_sq if old else None),
                           products=copy(arrays[prefix + "products"], old.products if old else None),
                           edges=edges, ends=ends)

    def _window_maps(self, prefix: str) -> dict[str, np.ndarray]:
        """S1, S2, S3 and σ from the sums, one fused pass (see maps_kernel)."""
        arrays = self._arrays
        exponential = self.mode == "exponential"
        n_px = self.shape[0] * self.shape[1]
        out = {name: np.empty(n_px if wanted else 0) for name, wanted in
               (("s1", self._do_abs), ("s2", self._do_ratio), ("s3", self._do_sigma),
                ("sigma", self._do_sigma))}
        # S1 is the correctly rounded Σ|ΔI|/(N-m), as in batch.s1; 2^-K is exact
        second, fourth = ("m2", "m2") if exponential else (prefix + "total", prefix + "total_sq")
        self._maps_step(arrays[prefix + "abs"], arrays[prefix + "ratio"], arrays[second], arrays[fourth],
                        self.pairs, 2.0**-self.scale_bits, self.window, out["s1"], out["s2"], out["s3"],
                        out["sigma"], self._weight_frames)
        return out

    def sigma(self) -> np.ndarray:
        """σ of Eq. 4 over the current window (grey levels), float64 (H, W); needs "s3"."""
        if not self._do_sigma:
            raise EstimatorError("sigma() needs 's3' among the estimators")
        if not self.ready:
            raise EstimatorError(f"the window is not full yet: {self.frames_seen} of "
                                 f"{self.window} frames pushed (check .ready)")
        return self._window_maps("" if self.mode != "tumbling" else "done_")["sigma"].reshape(self.shape)

    def _snapshot(self) -> dict[str, Any]:
        """Copies of the whole state (for tests and debugging), lag products brought up to date."""
        self._flush()
        state: dict[str, Any] = {name: array.copy() for name, array in self._arrays.items()}
        state.update(frames_seen=self.frames_seen, bits=self.bits,
                     blocks_completed=self.blocks_completed,
                     weights=(self._weight_frames, self._weight_pairs))
        return state

    def __repr__(self) -> str:
        return (f"SlidingWindow(shape={self.shape}, window={self.window}, lag={self.lag}, "
                f"q={self.q}, bits={self.bits}, estimators={self.estimators}, "
                f"mode={self.mode!r}, kernel={self.kernel!r}, frames_seen={self.frames_seen})")
