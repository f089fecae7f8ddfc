"""Region τc of disjoint windows (tumbling) without per-pixel lag products.

A region's τc is fitted to its pooled correlation Ĉ(k) = Σ_p cov_p(k) / Σ_p var_p
(docs/tau_c.md, "Regions"). When only regions are wanted (``analyze --timeline``), the
per-pixel lag products the engine keeps (one row per lag, plus a copy of the completed
window's) need not be kept: per pixel, over a window of N frames with T = ΣI, Q = ΣI²,
P_k = Σ_{t=1}^{N-k} I_t·I_{t+k} and E_k = the sum of the first k and the last k frames,
the covariance of docs/tau_c.md's estimator is (Σ_{t<=N-k} I_t + Σ_{t>k} I_t = 2T - E_k)::

    (N-k)·cov(k) = P_k - Ī·(2T - E_k) + (N-k)·Ī²,   Ī = T/N
    N²·(N-k)·cov(k) = N²·P_k + N·T·E_k - (N+k)·T²
    N²·var          = N·Q - T²

All of it is integer. Summed over the region's pixels, ΣP_k and ΣQ pool as the frames arrive
(a few scalars per frame); only ΣT·E_k and ΣT² need per-pixel values, once, at the window's
end: T, the sums of the first k frames (at the lags k of ``tau_lags(K)``) and the last K
frames (a ring that also gives each new frame its lag partners). Per pixel that is
K frames + L head sums + T: 41 bytes for 8-bit data at K = 20 (L = 9) and N <= 257, against the engine's
~250 (its lag products, edge sums and their copies). Hence::

    Ĉ(k) = [N²·ΣP_k + N·ΣT·E_k - (N+k)·ΣT²] / [(N-k)·(N·ΣQ - ΣT²)]

formed with exact integers (Python's, so no bound on the region's size) and divided once: the
same pooled correlation as :meth:`edgedsm.estimators.SlidingWindow.region_tau_c` (which forms
each pixel's covariances in float64 after an integer re-centring and then sums them) to
rounding, and the same fit. Pixels in several regions are pooled once per "atom" (the set of
pixels sharing one membership), so the cost does not grow with the number of regions.

Units: intensities in grey levels, τc in frames. Only tumbling windows (disjoint sets of N
frames, the paper's Figs. 10-11 processing): a sliding window would need the frames that
leave it, i.e. a ring of N frames, which the engine already keeps.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from edgedsm.errors import EstimatorError
from edgedsm.estimators.correlation_time import TauC, _check_mask, fit_pooled, max_lag_problem, tau_lags
from edgedsm.estimators.jit import compiled
from edgedsm.frames import sample_dtype

try:
    import numba
except ImportError:  # the 'fast' extra is not installed: numpy below
    numba = None

MAX_REGIONS = 62  # a pixel's membership is packed into the bits of one int64
#: Pixels per partial sum of a frame (a task of the parallel pass, small enough to stay in cache
#: while it is read once per lag); each term I·I' < 2^32, so the sum over a frame of fewer than
#: 2^31 pixels stays in int64 (the window's-end terms are larger: see _window_chunk).
CHUNK = 1 << 12


@compiled(parallel=True, nogil=True)
def _frame_kernel(frame: np.ndarray, ring: np.ndarray, labels: np.ndarray, uniform: np.ndarray, slots: np.ndarray,
                  pairs: int, write: int, first: bool, head_from: int, lag_values: np.ndarray, total: np.ndarray,
                  head: np.ndarray, chunk: int, out: np.ndarray) -> None:
    """One frame: out[c, a, j] += Σ I·I_{-k_j} (j < pairs), out[c, a, L] += Σ I² over the pixels
    of chunk c in atom a+1; T += I; head rows j >= head_from += I; the frame into ring[write].

    Per chunk and atom the frame is masked once (0 outside the atom), then each lag is a plain
    multiply-add over the chunk, which vectorises (a test of the label inside the lag loops
    does not). A chunk wholly in one atom (``uniform[c]`` = its label) takes the frame as it is;
    a chunk in no region (``uniform[c]`` = -1) is skipped (its sums are never read)."""
    pixels = frame.size
    lags = lag_values.size
    atoms = out.shape[1]
    for c in numba.prange(out.shape[0]):
        if uniform[c] < 0:
            continue
        lo = c * chunk
        hi = min(pixels, lo + chunk)
        masked = np.empty(hi - lo, np.int64)
        for atom in range(atoms):
            if uniform[c] > 0 and uniform[c] != atom + 1:
                continue
            present = hi - lo
            if uniform[c] > 0:
                for p in range(lo, hi):
                    masked[p - lo] = frame[p]
            else:
                present = 0
                for p in range(lo, hi):
                    inside = labels[p] == atom + 1
                    masked[p - lo] = np.int64(frame[p]) if inside else 0
                    present += inside
            if present == 0:
                continue
            acc = np.int64(0)
            for i in range(hi - lo):
                acc += masked[i] * masked[i]
            out[c, atom, lags] += acc
            for j in range(pairs):
                row = ring[slots[j]]
                acc = np.int64(0)
                for i in range(hi - lo):
                    acc += masked[i] * np.int64(row[lo + i])
                out[c, atom, j] += acc
        for p in range(lo, hi):
            x = frame[p]
            total[p] = x if first else total[p] + x
            for j in range(head_from, lags):
                head[j, p] = x if first else head[j, p] + x
            ring[write, p] = x


@compiled(parallel=True, nogil=True)
def _window_kernel(total: np.ndarray, head: np.ndarray, ring: np.ndarray, labels: np.ndarray,
                   last_slots: np.ndarray, lag_values: np.ndarray, chunk: int, out: np.ndarray) -> None:
    """The window's end: out[c, a, j] += Σ T·E_{k_j}, out[c, a, L] += Σ T² (last_slots[s]: the ring
    slot of the s-th frame from the end)."""
    pixels = total.size
    lags = lag_values.size
    for c in numba.prange(out.shape[0]):
        for p in range(c * chunk, min(pixels, (c + 1) * chunk)):
            atom = np.int64(labels[p]) - 1
            if atom < 0:
                continue
            t = np.int64(total[p])
            out[c, atom, lags] += t * t
            tail = np.int64(0)
            done = 0
            for j in range(lags):
                while done < lag_values[j]:
                    tail += np.int64(ring[last_slots[done], p])
                    done += 1
                out[c, atom, j] += t * (np.int64(head[j, p]) + tail)


def _frame_numpy(frame: np.ndarray, ring: np.ndarray, labels: np.ndarray, uniform: np.ndarray, slots: np.ndarray,
                 pairs: int, write: int, first: bool, head_from: int, lag_values: np.ndarray, total: np.ndarray,
                 head: np.ndarray, chunk: int, out: np.ndarray) -> None:
    """_frame_kernel without numba (the same sums, whole rows at a time)."""
    lags = lag_values.size
    for c in range(out.shape[0]):
        part = slice(c * chunk, (c + 1) * chunk)
        x = frame[part].astype(np.int64)
        terms = [ring[slots[j], part].astype(np.int64) * x for j in range(pairs)] + [x * x]
        _pool_rows(labels[part], terms, [*range(pairs), lags], out[c])
    total[:] = frame if first else total + frame
    head[head_from:] = frame if first else head[head_from:] + frame
    ring[write] = frame


def _window_numpy(total: np.ndarray, head: np.ndarray, ring: np.ndarray, labels: np.ndarray,
                  last_slots: np.ndarray, lag_values: np.ndarray, chunk: int, out: np.ndarray) -> None:
    """_window_kernel without numba."""
    lags = lag_values.size
    for c in range(out.shape[0]):
        part = slice(c * chunk, (c + 1) * chunk)
        t = total[part].astype(np.int64)
        tails = np.cumsum(ring[last_slots[:int(lag_values[-1])], part].astype(np.int64), axis=0)
        terms = [t * (head[j, part].astype(np.int64) + tails[int(k) - 1]) for j, k in enumerate(lag_values)]
        _pool_rows(labels[part], [*terms, t * t], list(range(lags + 1)), out[c])


def _pool_rows(labels: np.ndarray, terms: list[np.ndarray], columns: list[int], out: np.ndarray) -> None:
    """out[a-1, columns[i]] += Σ terms[i] over the pixels labelled a (int64 dots: exact)."""
    for atom in range(out.shape[0]):
        inside = labels == atom + 1
        if inside.any():
            for column, term in zip(columns, terms, strict=True):
                out[atom, column] += int(term[inside].sum())


def _window_chunk(window: int, top: int) -> int:
    """Pixels per partial sum at the window's end: T·E_k < 2·(N·top)² (E_k <= 2K·top < 2N·top),
    and a chunk's sum must stay in int64 (0: not even one pixel's term fits)."""
    return min(CHUNK, 2**62 // (2 * (window * top) ** 2))


def int64_problem(shape: tuple[int, int], window: int, bits: int) -> str | None:
    """Why the partial sums would leave int64 (None: they stay in it): a frame's Σ I·I' (below
    pixels·(2^bits - 1)²) or one pixel's window-end term T·E_k (below 2·(N·(2^bits - 1))²)."""
    top = (1 << bits) - 1
    if _window_chunk(window, top) < 1:
        return f"a window of N={window} {bits}-bit frames is too long for exact int64 sums (use the engine's τc)"
    if int(shape[0]) * int(shape[1]) * top * top >= 2**63:
        return f"a {shape[1]}x{shape[0]} frame of {bits}-bit data is too large for exact int64 sums of one frame"
    return None


def _chunk_atoms(labels: np.ndarray, chunk: int) -> np.ndarray:
    """Per chunk of ``chunk`` pixels: its label when all its pixels share one atom, 0 when they
    do not, -1 when none is in a region."""
    pad = -labels.size % chunk
    rows = np.concatenate((labels, np.full(pad, labels[-1], labels.dtype))).reshape(-1, chunk).astype(np.int64)
    same = (rows == rows[:, :1]).all(axis=1)
    return np.where(same, np.where(rows[:, 0] > 0, rows[:, 0], -1), 0)


def atoms_of(masks: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Label every pixel by the set of regions it is in: (labels (P,), 0 = in none, 1..A the
    atoms; member (R, A) bool, region r holds atom a+1)."""
    code = np.zeros(masks[0].size, np.int64)
    for bit, mask in enumerate(masks):
        code |= mask.reshape(-1).astype(np.int64) << bit
    codes, inverse = np.unique(code, return_inverse=True)
    if codes[0] != 0:  # every pixel is in some region: label 0 stays unused
        codes, inverse = np.concatenate(([0], codes)), inverse + 1
    dtype = np.uint8 if codes.size <= 256 else np.uint16 if codes.size <= 65536 else np.int32
    member = ((codes[None, 1:] >> np.arange(len(masks))[:, None]) & 1).astype(bool)
    return inverse.astype(dtype), member


class TumblingRegionTau:
    """τc of each region over disjoint windows of N frames (frames 0..N-1, N..2N-1, ...).

    ``push`` takes the frames one at a time; when a window completes, ``last`` holds each
    region's :class:`TauC` (frames) for it, as ``SlidingWindow(..., mode="tumbling",
    max_lag=K).region_tau_c(mask)`` would give. Frames: 2-D uint8 (bits <= 8) or uint16
    arrays of ``shape``; ``bits`` their depth (1..16).
    """

    def __init__(self, shape: tuple[int, int], regions: Mapping[str, np.ndarray], window: int, max_lag: int,
                 bits: int) -> None:
        if not regions or len(regions) > MAX_REGIONS:
            raise EstimatorError(f"1 to {MAX_REGIONS} regions, got {len(regions)}")
        if not 1 <= bits <= 16:
            raise EstimatorError(f"bits must be 1..16, got {bits}")
        if problem := max_lag_problem(max_lag, window):
            raise EstimatorError(problem)
        if problem := int64_problem(shape, window, bits):
            raise EstimatorError(problem)
        top = (1 << bits) - 1
        self._window_chunk = _window_chunk(window, top)
        self.shape = (int(shape[0]), int(shape[1]))
        self.names = tuple(regions)
        masks = [_check_mask(mask, self.shape) for mask in regions.values()]
        self.labels, self._member = atoms_of(masks)
        self._uniform = _chunk_atoms(self.labels, CHUNK)
        self.window, self.max_lag, self.bits = int(window), int(max_lag), int(bits)
        self.lags = tau_lags(self.max_lag)
        pixels = self.shape[0] * self.shape[1]
        self._frame_type = sample_dtype(bits)
        self._ring = np.zeros((self.max_lag, pixels), self._frame_type)  # the last K frames, frame j in slot j % K
        self._total = np.zeros(pixels, np.uint16 if window * top <= 0xFFFF else
                               np.uint32 if window * top <= 0xFFFFFFFF else np.int64)
        self._head = np.zeros((self.lags.size, pixels), np.uint16 if self.max_lag * top <= 0xFFFF else np.uint32)
        atoms = self._member.shape[1]
        self._frame_out = np.zeros((-(-pixels // CHUNK), atoms, self.lags.size + 1), np.int64)
        self._window_out = np.zeros((-(-pixels // self._window_chunk), atoms, self.lags.size + 1), np.int64)
        self._pooled = [[0] * (self.lags.size + 1) for _ in range(atoms)]  # Python ints: exact, unbounded
        self.frames_seen = 0
        self.last: dict[str, TauC] | None = None  # the last completed window's τc per region

    @property
    def bytes_per_pixel(self) -> float:
        """Memory of the per-pixel state (ring, head sums, T, labels), bytes per pixel."""
        arrays = (self._ring, self._total, self._head, self.labels)
        return sum(array.nbytes for array in arrays) / (self.shape[0] * self.shape[1])

    def push(self, frame: np.ndarray) -> dict[str, TauC] | None:
        """Take the next frame; at a window's last frame, return (and keep in ``last``) each
        region's τc of that window."""
        if frame.shape != self.shape or frame.dtype != self._frame_type or not frame.flags.c_contiguous:
            raise EstimatorError(f"frames must be C-contiguous {self._frame_type} arrays of shape {self.shape}, "
                                 f"got {frame.dtype} {frame.shape}")
        position = self.frames_seen % self.window
        pairs = int(np.searchsorted(self.lags, position, side="right"))  # lags k <= position: a frame k before
        slots = np.ascontiguousarray((position - self.lags) % self.max_lag)
        head_from = pairs if position < self.max_lag else self.lags.size  # heads of k > position take the frame
        out = self._frame_out
        out.fill(0)
        kernel = _frame_kernel if numba is not None else _frame_numpy
        kernel(frame.reshape(-1), self._ring, self.labels, self._uniform, slots, pairs, position % self.max_lag,
               position == 0, head_from, self.lags, self._total, self._head, CHUNK, out)
        self._add(out)
        self.frames_seen += 1
        if position < self.window - 1:
            return None
        ends = np.array([(position - s) % self.max_lag for s in range(self.max_lag)], np.int64)
        out = self._window_out
        out.fill(0)
        (_window_kernel if numba is not None else _window_numpy)(self._total, self._head, self._ring, self.labels,
                                                                 ends, self.lags, self._window_chunk, out)
        window_sums = [[int(v) for v in atom] for atom in out.astype(object).sum(axis=0)]
        self.last = {name: self._fit(member, window_sums) for name, member in zip(self.names, self._member,
                                                                                 strict=True)}
        self._pooled = [[0] * (self.lags.size + 1) for _ in self._pooled]
        return self.last

    def _add(self, out: np.ndarray) -> None:
        """Add one frame's partial sums (chunks, atoms, L+1) into the window's Python ints."""
        sums = out.sum(axis=0)  # < pixels·(2^bits - 1)² < 2^63 (checked at the start)
        for atom, row in enumerate(sums):
            pooled = self._pooled[atom]
            for j, value in enumerate(row):
                pooled[j] += int(value)

    def _fit(self, member: np.ndarray, window_sums: list[list[int]]) -> TauC:
        """Ĉ(k) of the atoms in ``member`` pooled (module docstring), then the engine's fit."""
        n, lags = self.window, self.lags.size
        chosen = np.flatnonzero(member)
        products = [sum(self._pooled[a][j] for a in chosen) for j in range(lags + 1)]  # ΣP_k, then ΣQ
        edges = [sum(window_sums[a][j] for a in chosen) for j in range(lags + 1)]  # ΣT·E_k, then ΣT²
        squares = edges[lags]
        spread = n * products[lags] - squares  # N²·Σvar
        cov = [(n * n * products[j] + n * edges[j] - (n + int(k)) * squares) / (n * n * (n - int(k)))
               for j, k in enumerate(self.lags)]
        return fit_pooled(np.array(cov)[:, None], np.array([spread / (n * n)]), n, self.lags)
