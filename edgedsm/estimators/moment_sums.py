"""The S1/S2/S3 accumulators of the streaming engine (paper Eq. 1-4), with the temporal contrast,
Fujii and inertia moment (issue 24) formed from the same sums: their sums, push kernels, maps.

One accumulator keeps, per pixel, what S1, S2 and S3 are formed from (only the sums of the maps
asked for), pushes each frame into them with the kernel module's fused pass, and turns them into
maps with :func:`edgedsm.estimators.activity.pixel_values` (the per-pixel arithmetic, written
once; region statistics read the same sums through :mod:`edgedsm.estimators.region_stats`).

- :class:`WindowMoments` (sliding and tumbling windows): Σ|I_j - I_{j+m}| (Eq. 1), the S2 terms
  in fixed point (Eq. 2, :mod:`edgedsm.estimators.fixed_point`), ΣI and ΣI² (Eq. 4) and, only
  when "im" is asked for, Σ(I_j - I_{j+m})², exact integers: what a push adds it subtracts when
  the frame leaves, so nothing drifts.
- :class:`ExponentialMoments`: the weighted means of |ΔI|, of the S2 term and ("im") of (ΔI)²
  and the weighted mean and M2 of the intensity, weights λ^k with λ = 1 - 1/N, float64
  (docs/engine.md).

Which sums a map needs: S1 Σ|ΔI|; S2 and Fujii (200·S2 at q = 0) the S2 terms; S3 Σ|ΔI| and
ΣI, ΣI²; contrast (σ/⟨I⟩) ΣI, ΣI²; IM Σ(ΔI)². Units: grey levels (S1, ΣI), grey levels² (ΣI²,
M2, Σ(ΔI)²), dimensionless (S2 terms); N and m in frames.
The accumulators know nothing of rings and modes: the engines (engine_sliding, engine_tumbling,
engine_exponential) hand them the frames and the sums to update.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from types import ModuleType
from typing import Any

import numpy as np

from edgedsm.estimators.fixed_point import _NO_LUT, TABLED_KINDS, ratio_lut
from edgedsm.estimators.registry import KernelSpec

_INT32_MAX = 2**31 - 1

Layout = dict[str, tuple[tuple[int, ...], Any]]

#: The inertia moment's sum where "im" was not asked for: no array in the state (existing layouts
#: unchanged), an empty one for the kernels, whose compiled branch never reads it.
_NO_SQ = {False: np.zeros(0, np.int64), True: np.zeros(0, np.float64)}


def sum_dtype(largest: int) -> type[np.signedinteger[Any]]:
    """int32 when the largest value a sum can reach fits, else int64 (less memory traffic)."""
    return np.int32 if largest <= _INT32_MAX else np.int64


class Moments:
    """What both accumulators share: which maps are kept, and the maps from the sums."""

    exponential = False
    #: The sums a snapshot copies (names of the engine's arrays).
    snapshot_names: tuple[str, ...] = ()
    #: The sums activity.pixel_values reads, in its argument order (abs, ratio, second, fourth, sq).
    value_names: tuple[str, ...] = ("abs", "ratio", "total", "total_sq", "sq")

    def __init__(self, estimators: tuple[str, ...], window: int, lag: int, q: float) -> None:
        self.window = window
        self.pairs = window - lag  # N - m pairs per window (Eq. 1-3)
        self.q = q
        #: the values the fused maps pass forms for the maps asked for (the registry's inputs)
        self.spec = KernelSpec.of(estimators)
        self.do_abs, self.do_ratio = self.spec.s1, self.spec.s2
        self.do_sigma = self.spec.sigma  # σ's sums serve S3 and the contrast
        self.do_sq = self.spec.im
        self.ratio_unit = 1.0  # 2^-K, the S2 fixed-point unit (window modes)
        self.weights = (0.0, 0.0)  # exponential mode: Σλ^k over the frames and over the pairs
        self._maps: Callable[..., None] | None = None

    @property
    def flags(self) -> tuple[bool, bool, bool]:
        return self.do_abs, self.do_ratio, self.do_sigma

    def reset(self) -> None:
        """Forget every frame (the arrays are the engine's: it zeroes them)."""

    @property
    def weight_frames(self) -> float:
        """Σλ^k over the frames (exponential mode; 0 in the window modes)."""
        return self.weights[0]


    def maps(self, sums: Mapping[str, np.ndarray], pixels: int) -> dict[str, np.ndarray]:
        """S1, S2, S3, σ, contrast, Fujii, IM (flat float64, those formed for the maps asked for;
        others empty) from ``sums``, one fused pass of the maps kernel."""
        assert self._maps is not None, "bind() first"
        out = {name: np.empty(size) for name, size in self.spec.sizes(pixels).items()}
        inputs = (sums[name] if name != "sq" else _sq(sums, self.exponential) for name in self.value_names)
        self._maps(*inputs, self.pairs, self.ratio_unit, self.window, *out.values(), self.weight_frames)
        return out

    def maps_kernel(self, kernels: ModuleType, spec: KernelSpec, parallel: bool) -> Callable[..., None]:
        """The maps kernel of ``spec``, all pixels."""
        return kernels.maps_kernel(spec, parallel=parallel, exponential=self.exponential)

    def maps_step(self, kernels: ModuleType, spec: KernelSpec) -> Callable[..., None]:
        """The maps kernel of ``spec`` for one thread (snapshots: maps on another thread)."""
        return self.maps_kernel(kernels, spec, False)


class WindowMoments(Moments):
    """Exact integer sums of the window modes: Σ|ΔI| (``abs``), Σ S2 term·2^K (``ratio``), ΣI
    (``total``), ΣI² (``total_sq``) and Σ(ΔI)² (``sq``). ``keep_totals``: ΣI and ΣI² are kept for
    τc as well."""

    snapshot_names = ("abs", "ratio", "total", "total_sq", "sq")

    def __init__(self, estimators: tuple[str, ...], window: int, lag: int, q: float, keep_totals: bool) -> None:
        super().__init__(estimators, window, lag, q)
        self.do_totals = self.do_sigma or keep_totals  # ΣI and ΣI² serve S3 and τc
        self.lut = _NO_LUT
        self.scale = 1.0  # 2^K
        self._grow: Callable[..., None] | None = None
        self._slide: Callable[..., None] | None = None
        self._pairs: Callable[..., None] | None = None

    def layout(self, pixels: int, bits: int) -> Layout:
        """Name -> (shape, dtype) of the sums; the sums of maps not asked for get 0 pixels."""
        top = (1 << bits) - 1
        n = self.window
        return {
            "abs": ((pixels if self.do_abs else 0,), sum_dtype(self.pairs * top)),
            "ratio": ((pixels if self.do_ratio else 0,), np.int64),
            "total": ((pixels if self.do_totals else 0,), sum_dtype(n * top)),
            "total_sq": ((pixels if self.do_totals else 0,), sum_dtype(n * top * top)),
            **({"sq": ((pixels,), sum_dtype(self.pairs * top * top))} if self.do_sq else {}),
        }

    def bind(self, kernels: ModuleType, kind: str, scale_bits: int, parallel: bool, slide: bool) -> None:
        """Pick the compiled kernels for the data's S2 term ``kind`` and K = ``scale_bits``;
        ``slide``: the kernels that also remove a leaving frame and pair (sliding window)."""
        self.ratio_unit = 2.0**-scale_bits
        self.scale = float(2**scale_bits)
        # "exact" terms are read from the same exactly rounded table as "lut" ones (equal entry by
        # entry, tests/unit/estimators): one gather per term costs less than a division and its
        # integer correction (docs/engine.md, "S2's term")
        tabled = kind in TABLED_KINDS and self.do_ratio
        self.lut = ratio_lut(self.q, scale_bits) if tabled else _NO_LUT
        sums = {"do_abs": self.do_abs, "do_ratio": self.do_ratio, "do_sq": self.do_sq}
        # "grow": add only (tumbling, and sliding until N frames are in); "slide": add and remove
        self._grow = kernels.window_kernel(do_sigma=self.do_totals, ratio_kind=kind, remove=False,
                                           parallel=parallel, **sums)
        if slide:
            self._slide = kernels.window_kernel(do_sigma=self.do_totals, ratio_kind=kind, remove=True,
                                                parallel=parallel, **sums)
            self._pairs = kernels.pairs_kernel(ratio_kind=kind, parallel=parallel, **sums)
        self._maps = self.maps_kernel(kernels, self.spec, parallel)

    def add(self, sums: Mapping[str, np.ndarray], new: np.ndarray, slot: np.ndarray, lagged: np.ndarray) -> None:
        """Frame i (``new``, then written into ``slot``) and the pair (i-m, i) join the sums;
        frame i-m is ``lagged`` (no pair yet: ``new`` itself, which adds |x-x| = 0 exactly)."""
        assert self._grow is not None
        self._grow(new, slot, lagged, lagged, sums["abs"], sums["ratio"], sums["total"], sums["total_sq"],
                   _sq(sums), self.lut, self.scale, self.q)

    def slide(self, sums: Mapping[str, np.ndarray], new: np.ndarray, slot: np.ndarray, lagged: np.ndarray,
              leaving: np.ndarray) -> None:
        """As :meth:`add`, and frame i-N (read from ``slot`` before frame i overwrites it) and
        the pair (i-N, i-N+m) (frame i-N+m: ``leaving``) leave the sums."""
        assert self._slide is not None
        self._slide(new, slot, lagged, leaving, sums["abs"], sums["ratio"], sums["total"], sums["total_sq"],
                    _sq(sums), self.lut, self.scale, self.q)

    def add_pair(self, sums: Mapping[str, np.ndarray], first: np.ndarray, second: np.ndarray) -> None:
        """The pair (first, second) joins Σ|ΔI|, the S2 sum and Σ(ΔI)² (rebuilding the sums)."""
        assert self._pairs is not None
        self._pairs(first, second, sums["abs"], sums["ratio"], _sq(sums), self.lut, self.scale, self.q)

    def rebuild(self, sums: Mapping[str, np.ndarray], frames: list[np.ndarray], lag: int) -> None:
        """Recompute ``sums`` (zeroed) from the window's ``frames`` in time order, O(N) per pixel."""
        if self.do_totals:
            total = np.zeros(frames[0].size, np.int64)
            total_sq = np.zeros(frames[0].size, np.int64)
            for frame in frames:
                wide = frame.astype(np.int64)
                total += wide
                total_sq += wide * wide
            sums["total"][:] = total
            sums["total_sq"][:] = total_sq
        for j in range(len(frames) - lag):
            self.add_pair(sums, frames[j], frames[j + lag])


class ExponentialMoments(Moments):
    """Exponentially weighted means (float64): |ΔI| (``abs``), the S2 term (``ratio``), (ΔI)²
    (``sq``), the intensity (``mean``) and its M2 (``m2``), with normalised (bias-free) weights."""

    exponential = True
    snapshot_names = ("abs", "ratio", "mean", "m2", "sq")
    value_names = ("abs", "ratio", "mean", "m2", "sq")  # σ² = M2/Σλ^k; the mean serves the contrast

    def __init__(self, estimators: tuple[str, ...], window: int, lag: int, q: float) -> None:
        super().__init__(estimators, window, lag, q)
        self.decay = 1.0 - 1.0 / window  # λ
        self._step: Callable[..., None] | None = None
        self.reset()

    def reset(self) -> None:
        self.weights = (0.0, 0.0)

    def layout(self, pixels: int, bits: int) -> Layout:
        sigma, abs_, ratio, sq = (pixels if on else 0 for on in (self.do_sigma, self.do_abs, self.do_ratio,
                                                                 self.do_sq))
        return {"mean": ((sigma,), np.float64), "m2": ((sigma,), np.float64), "abs": ((abs_,), np.float64),
                "ratio": ((ratio,), np.float64), **({"sq": ((sq,), np.float64)} if self.do_sq else {})}

    def bind(self, kernels: ModuleType, parallel: bool) -> None:
        self._step = kernels.exponential_kernel(do_abs=self.do_abs, do_ratio=self.do_ratio, do_sigma=self.do_sigma,
                                                parallel=parallel, do_sq=self.do_sq)
        self._maps = self.maps_kernel(kernels, self.spec, parallel)

    def push(self, sums: Mapping[str, np.ndarray], new: np.ndarray, slot: np.ndarray, has_pair: bool) -> None:
        """Frame i (``new``) joins the weighted means, and the pair (i-m, i) with frame i-m read
        from ``slot`` (then overwritten by frame i) when ``has_pair`` (i >= m)."""
        assert self._step is not None
        frames, pairs = self.weights
        frames = self.decay * frames + 1.0
        if has_pair:
            pairs = self.decay * pairs + 1.0
        self.weights = (frames, pairs)
        # before frame m there is no pair: weight 0 leaves the pair means unchanged
        self._step(new, slot, sums["mean"], sums["m2"], sums["abs"], sums["ratio"], _sq(sums, True), self.decay,
                   1.0 / frames,
                   1.0 / pairs if has_pair else 0.0, self.q)


def _sq(sums: Mapping[str, np.ndarray], exponential: bool = False) -> np.ndarray:
    """The Σ(ΔI)² sums (or weighted mean), or an empty array where "im" is not kept."""
    return sums["sq"] if "sq" in sums else _NO_SQ[exponential]
