"""The frequency-band accumulator of the streaming engine: a few DFT bins per pixel, and from them
the band powers of :mod:`edgedsm.estimators.bands` ("band_low", "band_high", "band_ratio" about a
split; "bands": any bands (lo, hi], the bins of each kept).

Definition (the batch reference, :mod:`edgedsm.estimators.bands`): X_j = Σ_k I_k e^{-2πi jk/N} over
the window's N frames (k = 0 oldest), P_j = c_j |X_j|²/N² with c_j = 2 below N/2, 1 at N/2, f_j =
j/(N Δt); the low band is (0, split], the high band (split, Nyquist], low + high = σ² (Parseval).
For j >= 1, X_j does not change when a constant is added to every I_k (Σ_k e^{-2πi jk/N} = 0), so
the bins are kept of the intensities minus any per-pixel offset: only differences of intensities
ever enter them (|X_j| <= N·D, D the spread of the values, whatever their mean).

Of the split only the bins of the smaller band are kept; the other band is σ² minus it (clamped at
0), σ² from the exact integer sums ΣI and ΣI² the S1/S2/S3 accumulator keeps: 16 bytes (re, im
float64) per kept bin per pixel, about half of ⌊N/2⌋ bins or fewer. Any bands keep their own bins
(a bin shared with another band or the split's side once).

- sliding: the sliding DFT, X_j ← W_j (X_j - I_{i-N} + I_i), W_j = e^{2πij/N} (Jacobsen & Lyons,
  "The sliding DFT", IEEE Signal Processing Magazine 20(2), 2003). While the window fills, the
  leaving value is frame 0's (the window starts as N copies of frame 0, whose bins j >= 1 are 0).
  Rounding grows with the recursion, so each push also recomputes the bins of 1/N of the pixels
  exactly from the ring (``reanchor``, an FFT of their N frames): every pixel is re-anchored every
  N pushes, at O(⌊N/2⌋ log N) per pixel amortised over N pushes, with no pause at any one push.
- tumbling: X_j += (I_t - I_0) e^{-2πi jt/N} for frame t of the block (I_0 its first frame, kept
  in ``band_origin``): a direct sum, no recursion.
- exponential: refused. An exponentially weighted DFT (X_j ← λ W_j X_j + I_i) exists, but its
  bins leak into each other and no Parseval identity ties them to the weighted σ²: the bands need
  a finite window.

Error bound (docs/engine.md): |band - batch band| <= BOUND_FACTOR · N · ε · D² per band, ε = 2^-53,
D the largest difference between two of the pixel's intensities over its last 2N frames (at most
2^bits - 1). It is a measured bound, not a proof: at most 0.41 · N · ε · D² was seen (a full-scale
tone, sliding mode, N = 8..128, 12 windows; tests/unit/estimators/test_streaming_bands.py holds
every run to it). Without the re-anchor the sliding DFT's rounding walks away as about √pushes
(0.46, 1.6, 4.6 and 15 N·ε·D² after 10³, 10⁴, 10⁵ and 10⁶ pushes at N = 16, 16-bit noise).

Units: bins in grey levels (frame intensities), band powers in grey levels², frequencies in Hz
with Δt (seconds), else cycles per frame.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from types import ModuleType
from typing import Any

import numpy as np

from edgedsm.errors import EstimatorError
from edgedsm.estimators import registry
from edgedsm.estimators.bands import band_members, frequencies, ratio
from edgedsm.estimators.value_set import window_spreads
from edgedsm.frames import sample_dtype

Layout = dict[str, tuple[tuple[int, ...], Any]]

#: The engine's names of the band maps (grey levels², grey levels², dimensionless).
BAND_NAMES: tuple[str, ...] = ("band_low", "band_high", "band_ratio")
#: Bytes one kept bin costs per pixel (its real and imaginary parts, float64).
BIN_BYTES = 16
#: The stated error bound's constant: |band - batch| <= BOUND_FACTOR · N · ε · D² (module doc).
BOUND_FACTOR = 2.0
_EPS = 2.0**-53
REANCHOR_BLOCK = 512  # pixels per FFT of the re-anchor


@dataclass(frozen=True)
class BandPlan:
    """Which DFT bins a window of ``window`` frames keeps: for the split ``split`` (Hz with ``dt``
    in seconds, else cycles per frame; None: half the Nyquist frequency, as ``bands.split_powers``)
    the smaller band's, when ``split_on``; and every bin of the ``custom`` bands (lo, hi]."""

    window: int
    dt: float | None
    split: float
    low: np.ndarray  # the bins j of (0, split]
    high: np.ndarray  # the bins j of (split, Nyquist]
    split_on: bool = True  # band_low, band_high or band_ratio asked for
    custom: tuple[np.ndarray, ...] = ()  # the bins j of each band of ``bands``

    @classmethod
    def of(cls, window: int, dt: float | None, split: float | None, bands: Sequence[tuple[float, float]] = (),
           split_on: bool = True) -> BandPlan:
        if dt is not None and (isinstance(dt, bool) or not isinstance(dt, int | float | np.integer | np.floating)):
            raise EstimatorError(f"the frame interval dt must be a number of seconds, got {dt!r}")
        freq = frequencies(window, dt)  # refuses dt <= 0; Hz, else cycles per frame
        custom = tuple(band_members(window, list(bands), dt)) if bands else ()
        nyquist = 0.5 / (1.0 if dt is None else float(dt))
        value = nyquist / 2 if split is None else split
        j = np.arange(freq.size)
        if not split_on:
            return cls(window, None if dt is None else float(dt), float(value), j[:0], j[:0], False, custom)
        if isinstance(value, bool) or not isinstance(value, int | float | np.integer | np.floating) \
                or not (np.isfinite(value) and 0 < value < nyquist):
            unit = "Hz" if dt is not None else "cycles per frame"
            raise EstimatorError(f"the band split must lie between 0 and the Nyquist frequency {nyquist:.6g} {unit}, "
                                 f"got {split!r}")
        if freq[-1] <= value:  # an odd N has no bin at Nyquist: as bands.band_power, refused
            raise EstimatorError(f"no frequency of a {window}-frame window lies above the band split {value:.6g}: "
                                 f"its highest is {freq[-1]:.6g} {'Hz' if dt is not None else 'cycles per frame'}")
        return cls(window, None if dt is None else float(dt), float(value),
                   j[(freq > 0) & (freq <= value)], j[freq > value], True, custom)

    @property
    def keeps_low(self) -> bool:
        """The low band's bins are kept (it has no more of them than the high band)."""
        return self.low.size <= self.high.size

    @property
    def side(self) -> np.ndarray:
        """The bins j of the split's smaller band (none without ``split_on``)."""
        return self.low if self.keeps_low else self.high

    @property
    def kept(self) -> np.ndarray:
        """The bins j kept per pixel, ascending: the split's smaller band's and the custom bands'."""
        return np.union1d(self.side, np.concatenate([self.side[:0], *self.custom])).astype(np.int64)

    def weights(self) -> np.ndarray:
        """c_j / N² of each kept bin: P_j = c_j |X_j|²/N² (Eq. 4 of bands.py)."""
        n = self.window
        return np.where(2 * self.kept == n, 1.0, 2.0) / float(n * n)


def error_bound(window: int, spread: float | np.ndarray) -> float | np.ndarray:
    """Bound on |band power - batch band power|, grey levels², over a window of ``window`` frames
    for pixels whose intensities spread over ``spread`` grey levels at most in their last 2N
    frames (module doc; 2^bits - 1 covers every pixel)."""
    return BOUND_FACTOR * window * _EPS * np.square(spread, dtype=np.float64)


def band_mode_problem(mode: str) -> str | None:
    """Why the bands cannot stream in window ``mode`` (None: they can); the one statement of it
    (engine, config)."""
    return registry.mode_problem(BAND_NAMES[0], mode)  # every band's one statement


def band_plan(estimators: tuple[str, ...], mode: str, window: int, dt: float | None,
              split: float | None, bands: Sequence[tuple[float, float]] | None = None) -> BandPlan | None:
    """The plan of the band maps among ``estimators`` (None: none asked for); refused in the
    exponential mode (module doc), and "bands" without ``bands``."""
    split_on = bool(set(estimators) & set(BAND_NAMES))
    if not split_on and "bands" not in estimators:
        return None
    if problem := band_mode_problem(mode):
        raise EstimatorError(problem)
    if "bands" in estimators and not bands:
        raise EstimatorError("estimator 'bands' needs the bands: bands=[(lo, hi), ...] (Hz with dt, else cycles "
                             "per frame)")
    return BandPlan.of(window, dt, split, bands if "bands" in estimators and bands else (), split_on)


class DftBins:
    """The kept DFT bins of every pixel (array ``bins``, shape (2, B, P): real and imaginary
    parts), their push kernels and the band maps. ``on``: a band map was asked for (otherwise
    there are no arrays and pushes do nothing)."""

    def __init__(self, window: int, plan: BandPlan | None) -> None:
        self.window = window
        self.plan = plan
        self.on = plan is not None
        self.ks = plan.kept if plan is not None else np.zeros(0, np.int64)
        turns = np.arange(window) * (2 * np.pi / window)  # 2π r/N, r = (j·t) mod N: exact indices
        self._cos, self._sin = np.cos(turns), np.sin(turns)
        self._step: Callable[..., None] | None = None

    @property
    def count(self) -> int:
        """B, the bins kept per pixel."""
        return int(self.ks.size)

    def layout(self, pixels: int, bits: int, origin: bool = False) -> Layout:
        """``bins`` (2, B, P) float64; with ``origin`` (tumbling) ``band_origin``, the block's first
        frame (the offset its bins are kept of). No arrays when no band map was asked for."""
        if not self.on:
            return {}
        layout: Layout = {"bins": ((2, self.count, pixels), np.float64)}
        if origin:
            layout["band_origin"] = ((pixels,), sample_dtype(bits))
        return layout

    def bind(self, kernels: ModuleType, parallel: bool, rotate: bool) -> None:
        """``rotate``: the sliding DFT's step X ← W(X + d); else the block sum X += d·e^{-2πi jt/N}."""
        if self.on:
            self._step = kernels.dft_kernel(rotate, parallel)

    # ----------------------------------------------------------------- sliding
    def slide(self, arrays: Mapping[str, np.ndarray], new: np.ndarray, leaving: np.ndarray) -> None:
        """Frame i (``new``) joins and ``leaving`` (frame i-N; while the window fills, frame 0)
        leaves: X_j ← W_j (X_j + I_i - I_leaving), W_j = e^{2πij/N}."""
        if self._step is None:
            return
        r = self.ks % self.window
        self._step(new, leaving, self._cos[r], self._sin[r], arrays["bins"])

    def reanchor(self, arrays: Mapping[str, np.ndarray], ring: np.ndarray, frames_seen: int,
                 pixels: slice | None = None) -> None:
        """Recompute the bins of the window's last N frames exactly (an FFT of ring slot j % N,
        frame j, in time order, minus the oldest frame) at ``pixels``: by default the chunk
        (frames_seen mod N) of N chunks, so every pixel is re-anchored every N pushes."""
        if not self.on or frames_seen == 0:
            return
        n = self.window
        if pixels is None:
            size = ring.shape[1]
            chunk = frames_seen % n
            pixels = slice(chunk * size // n, (chunk + 1) * size // n)
            if pixels.start == pixels.stop:
                return
        # while the window fills, frame 0 stands for the frames before it (as in ``slide``)
        slots = [max(j, 0) % n for j in range(frames_seen - n, frames_seen)]
        bins = arrays["bins"]
        # in blocks: arrays of a few hundred KiB are reused by the allocator, larger ones are new
        # pages each time, whose faults cost several times the FFT
        first, stop, _ = pixels.indices(ring.shape[1])
        for start in range(first, stop, REANCHOR_BLOCK):
            part = slice(start, min(start + REANCHOR_BLOCK, stop))
            window = ring[slots, part].astype(np.float64)
            window -= window[0]  # only differences: |X_j| <= N·D however bright the pixel
            spectrum = np.fft.rfft(window, axis=0)[self.ks]
            bins[0, :, part] = spectrum.real
            bins[1, :, part] = spectrum.imag

    # ----------------------------------------------------------------- tumbling
    def add(self, arrays: Mapping[str, np.ndarray], new: np.ndarray, position: int) -> None:
        """Frame t = ``position`` of the block joins: X_j += (I_t - I_0) e^{-2πi jt/N}."""
        if self._step is None:
            return
        origin = arrays["band_origin"]
        if position == 0:
            origin[:] = new  # its own term is 0
            return
        r = (self.ks * position) % self.window
        self._step(new, origin, self._cos[r], self._sin[r], arrays["bins"])

    # ----------------------------------------------------------------- maps
    def maps(self, sums: Mapping[str, np.ndarray], names: tuple[str, ...], q: float) -> dict[str, np.ndarray]:
        """The float64 band maps ``names`` (of BAND_NAMES, and "bands": (K, ...), one row per
        custom band) from the kept bins (2, B, ...) and σ² (from the exact sums ``total``,
        ``total_sq``, shaped as the pixels: flat (P,), or a region's box of views); the split's
        other band is σ² minus the kept one, >= 0. A pixel with σ = 0 (constant) reads 0 in every
        band."""
        plan = self.plan
        assert plan is not None
        n = self.window
        bins = sums["bins"]
        rows = {int(j): (row, weight) for row, (j, weight) in enumerate(zip(plan.kept.tolist(),
                                                                              plan.weights().tolist(), strict=True))}
        variance = window_spreads(sums["total"], sums["total_sq"], n) / float(n * n)
        flat = variance == 0
        scratch = (np.empty(bins.shape[2:]), np.empty(bins.shape[2:]))

        def power(members: np.ndarray) -> np.ndarray:
            """Σ P_j over the bins ``members``, P_j = c_j/N² · (re² + im²), in place (no temporaries
            per bin: they cost three times the arithmetic), 0 where σ = 0."""
            total, (square, other) = np.zeros(bins.shape[2:]), scratch
            for j in members.tolist():
                row, weight = rows[j]
                np.multiply(bins[0, row], bins[0, row], out=square)
                np.multiply(bins[1, row], bins[1, row], out=other)
                square += other
                square *= weight
                total += square
            total[flat] = 0.0
            return total

        out: dict[str, np.ndarray] = {}
        if "bands" in names:
            out["bands"] = np.stack([power(members) for members in plan.custom])
        if set(names) & set(BAND_NAMES):
            kept = power(plan.side)
            other = np.maximum(variance - kept, 0.0)
            low, high = (kept, other) if plan.keeps_low else (other, kept)
            out.update(band_low=low, band_high=high)
            if "band_ratio" in names:
                out["band_ratio"] = ratio(low, high, q)
        return {name: out[name] for name in names}
