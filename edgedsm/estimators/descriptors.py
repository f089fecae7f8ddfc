"""The biospeckle field's descriptors beside S1-S3 (issue 24): batch references, in float64, as
the field's reference toolbox BSLTL 1.3.1 (Octave package ``bsltl``) defines them, and the names
``edgedsm analyze --estimator`` accepts (``DESCRIPTORS``: a view of
:mod:`edgedsm.estimators.registry`, whose records name these functions).

Every function takes a stack of N frames, shape (N, H, W), of finite intensities >= 0 (grey
levels for camera data; checked by :func:`edgedsm.estimators.batch.check_frames`) and returns an
(H, W) float64 map. BSLTL's functions take a double (H, W, N) array; they are written with the
time axis first here. Where BSLTL compares frames 1 apart only, the lag m is a parameter whose
default 1 is BSLTL's.

Degenerate pixels (defined, never NaN or inf; BSLTL returns NaN for some of them):
- a constant pixel (dark, saturated or any fixed level): every difference is 0, so Fujii, GD,
  IM and the motion history are 0; σ = 0, so contrast, skewness and kurtosis are defined as 0
  (BSLTL: 0/0 = NaN for skewness and kurtosis, and for contrast where the mean is 0);
- Fujii where I_k + I_{k+m} = 0: that pair contributes 0 (BSLTL's +eps gives the same).
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass

import numpy as np

from edgedsm.errors import EstimatorError
from edgedsm.estimators import bands
from edgedsm.estimators.batch import check_frames, check_stack, s2, temporal_sigma
from edgedsm.estimators.registry import REGISTRY, Record, load
from edgedsm.estimators.value_set import gd_of_sum

#: Octave's eps (2^-52), which BSLTL's fujii.m adds to I_k + I_{k+m}: with it each term is
#: BSLTL's; q = 0 would differ where I_k + I_{k+m} = 1, by 1 ulp. (The map still differs from
#: BSLTL's by about 1 ulp: it scales by 200 before dividing by N-1, S2 the other way round.)
BSLTL_EPS = 2.0**-52

#: Integer stacks whose exact sums fit int64 with this margin are summed in integers.
_INT64_LIMIT = 2**62


def _at_least_two(frames: np.ndarray) -> np.ndarray:
    stack = check_frames(frames)
    if stack.shape[0] < 2:
        raise EstimatorError(f"a descriptor needs N >= 2 frames, got N={stack.shape[0]}")
    return stack


def _small_integers(stack: np.ndarray) -> bool:
    return np.issubdtype(stack.dtype, np.integer) and stack.dtype.itemsize <= 2


def fujii(frames: np.ndarray, lag: int = 1) -> np.ndarray:
    """Fujii's method, BSLTL ``fujii.m`` (there m = 1):
    F = 200/(N-m) Σ_{k=1}^{N-m} |I_k - I_{k+m}| / (I_k + I_{k+m} + eps) = 200 · S2(q = eps) (Eq. 2).
    Dimensionless, 0..200."""
    return 200.0 * s2(frames, lag, q=BSLTL_EPS)


def gd(frames: np.ndarray) -> np.ndarray:
    """Generalized differences, BSLTL ``gendiff.m``: GD = Σ_{i<j} |I_i - I_j| / C(N, 2), every
    pair of the N frames (no lag). Grey levels.

    Computed in O(N log N) per pixel and one sorted copy of the stack, without the O(N²) pairs:
    for the values sorted ascending, x_(0) <= ... <= x_(N-1), Σ_{i<j} |x_i - x_j| =
    Σ_k (2k - N + 1) x_(k) (each x_(k) is the larger of k pairs and the smaller of N-1-k).
    Integer data (8-16 bits) are summed exactly in int64, so the map is the exact sum rounded
    once by the division (as BSLTL's double sums are, while they stay below 2^53)."""
    stack = _at_least_two(frames)
    n = stack.shape[0]
    ordered = np.sort(stack, axis=0)
    pairs = n * (n - 1) / 2
    if _small_integers(stack) and n * n * int(np.iinfo(stack.dtype).max) < _INT64_LIMIT:
        total = np.zeros(stack.shape[1:], np.int64)
        for k in range(n):
            total += (2 * k - n + 1) * ordered[k].astype(np.int64)
        return gd_of_sum(total, n)  # the sliding engine's map from its own sum, the same division
    # the weights sum to 0, so the smallest value can be taken off first: every term is then a
    # spread, not an intensity (no cancellation of large offsets in float data)
    lowest = ordered[0].astype(np.float64)
    total_f = np.zeros(stack.shape[1:], np.float64)
    for k in range(1, n):
        total_f += (2 * k - n + 1) * (ordered[k].astype(np.float64) - lowest)
    return total_f / pairs


def im(frames: np.ndarray, lag: int = 1) -> np.ndarray:
    """Inertia moment of each pixel's time history, BSLTL ``graphim.m`` (there m = 1):
    IM = 1/(N-m) Σ_{k=1}^{N-m} (I_k - I_{k+m})². Grey levels². Integer data: exact int64 sums."""
    stack = check_stack(frames, lag)
    n = stack.shape[0]
    exact = _small_integers(stack) and n * int(np.iinfo(stack.dtype).max) ** 2 < _INT64_LIMIT
    kind = np.int64 if exact else np.float64
    total = np.zeros(stack.shape[1:], kind)
    for k in range(n - lag):
        diff = stack[k].astype(kind) - stack[k + lag].astype(kind)
        total += diff * diff
    return total.astype(np.float64) / (n - lag)


def _mean(stack: np.ndarray) -> np.ndarray:
    """⟨I⟩ over time; integer data from an exact int64 sum."""
    if _small_integers(stack):
        return stack.sum(axis=0, dtype=np.int64).astype(np.float64) / stack.shape[0]
    return stack.astype(np.float64).mean(axis=0)


def contrast(frames: np.ndarray) -> np.ndarray:
    """Temporal speckle contrast, BSLTL ``stdcont.m``: C = σ/⟨I⟩ with σ the population standard
    deviation of Eq. 4. Dimensionless. C = 0 where ⟨I⟩ = 0 (a dark pixel; BSLTL: NaN)."""
    stack = _at_least_two(frames)
    mean = _mean(stack)
    result = np.zeros_like(mean)
    np.divide(temporal_sigma(stack), mean, out=result, where=mean > 0)
    return result


def _central_sums(stack: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Σd², Σd³, Σd⁴) of the deviations d from the temporal mean, in some common unit.

    Integer data: d = N·I - ΣI is an exact integer (scaled by N, which cancels in the
    standardised moments), so no rounding happens before the powers."""
    n = stack.shape[0]
    if _small_integers(stack):
        total = stack.sum(axis=0, dtype=np.int64)
        dev = ((n * frame.astype(np.int64) - total).astype(np.float64) for frame in stack)
    else:
        mean = stack.astype(np.float64).mean(axis=0)
        dev = (frame.astype(np.float64) - mean for frame in stack)
    zero = np.zeros(stack.shape[1:], np.float64)
    m2, m3, m4 = zero.copy(), zero.copy(), zero.copy()
    for d in dev:
        square = d * d
        m2 += square
        m3 += square * d
        m4 += square * square
    return m2, m3, m4


def skewness(frames: np.ndarray) -> np.ndarray:
    """Temporal skewness, BSLTL ``graphskew.m``: 1/N Σ ((I_k - ⟨I⟩)/σ)³ with the population σ
    = √N Σd³ / (Σd²)^(3/2) for the deviations d. Dimensionless. 0 where σ = 0 (BSLTL: NaN)."""
    stack = _at_least_two(frames)
    m2, m3, _ = _central_sums(stack)
    result = np.zeros_like(m2)
    np.divide(np.sqrt(stack.shape[0]) * m3, m2 * np.sqrt(m2), out=result, where=m2 > 0)
    return result


def kurtosis(frames: np.ndarray) -> np.ndarray:
    """Temporal kurtosis (not excess: 3 for Gaussian noise), BSLTL ``graphkurt.m``:
    1/N Σ ((I_k - ⟨I⟩)/σ)⁴ = N Σd⁴ / (Σd²)². Dimensionless. 0 where σ = 0 (BSLTL: NaN)."""
    stack = _at_least_two(frames)
    m2, _, m4 = _central_sums(stack)
    result = np.zeros_like(m2)
    np.divide(stack.shape[0] * m4, m2 * m2, out=result, where=m2 > 0)
    return result


def mhi(frames: np.ndarray, threshold: float) -> np.ndarray:
    """Motion history image, BSLTL ``graphmhi.m``: MHI = Σ_{j=1}^{N-1} [|I_j - I_{j+1}| > U] ·
    255 j / Σ_{j=1}^{N-1} j, later changes weighted more; U (grey levels) is the threshold.
    Dimensionless, 0..255."""
    stack = _at_least_two(frames)
    threshold = float(threshold)
    if not np.isfinite(threshold) or threshold < 0:
        raise EstimatorError(f"the motion threshold must be a finite number >= 0 grey levels, got {threshold}")
    n = stack.shape[0]
    step = 255.0 / (n * (n - 1) / 2)
    result = np.zeros(stack.shape[1:], np.float64)
    for j in range(1, n):
        moved = np.abs(stack[j - 1].astype(np.float64) - stack[j].astype(np.float64)) > threshold
        result += moved * (step * j)
    return result


def band_low(frames: np.ndarray, dt: float | None = None, split: float | None = None) -> np.ndarray:
    """Periodogram power of each pixel in the low band (0, split] (:func:`bands.split_powers`),
    grey levels²."""
    return bands.split_powers(frames, dt, split)[0]


def band_high(frames: np.ndarray, dt: float | None = None, split: float | None = None) -> np.ndarray:
    """Periodogram power of each pixel in the high band (split, Nyquist], grey levels²."""
    return bands.split_powers(frames, dt, split)[1]


def band_ratio(frames: np.ndarray, dt: float | None = None, split: float | None = None,
               q: float = 0.0) -> np.ndarray:
    """High-band power / (low-band power + q) of each pixel (:func:`bands.ratio`), dimensionless."""
    return bands.ratio(*bands.split_powers(frames, dt, split), q=q)


@dataclass(frozen=True)
class Descriptor:
    """One name ``analyze --estimator`` accepts: its batch map and what a reader must know of it
    (a view of its :class:`~edgedsm.estimators.registry.Record`)."""

    compute: Callable[..., np.ndarray]  # (frames, *, lag, q, dt, split, threshold) -> (H, W) map
    unit: str
    uses_lag: bool
    bsltl: str | None  # the BSLTL function it reproduces (None: not in BSLTL)
    streaming: str  # the cost of a streaming version, or that there is none
    noise_floor: bool  # a noise floor exists (docs/noise.md)
    summary: str

    @classmethod
    def of(cls, record: Record) -> Descriptor:
        return cls(functools.partial(compute, record.name), record.unit, record.uses_lag, record.bsltl,
                   record.streaming(), record.has_floor, record.summary)


class _Descriptors(Mapping[str, Descriptor]):
    """The registry's maps with a batch reference, by name, in registry order (a live view: a
    record registered later is in it)."""

    def __getitem__(self, name: str) -> Descriptor:
        record = REGISTRY.get(name)
        if record is None or record.batch is None:
            raise KeyError(name)
        return Descriptor.of(record)

    def __iter__(self) -> Iterator[str]:
        return (name for name, record in REGISTRY.items() if record.batch is not None)

    def __len__(self) -> int:
        return sum(1 for _ in self)


#: The names ``edgedsm analyze --estimator`` accepts: a view of the registry.
DESCRIPTORS: Mapping[str, Descriptor] = _Descriptors()

#: The command-line option that gives each batch argument a descriptor may need.
_OPTIONS = {"threshold": "--threshold"}


def compute(name: str, frames: np.ndarray, *, lag: int = 1, q: float = 0.0, dt: float | None = None,
            split: float | None = None, threshold: float | None = None) -> np.ndarray:
    """The (H, W) map of the descriptor ``name`` (a key of ``DESCRIPTORS``) by its record's batch
    reference; arguments it does not use are ignored."""
    if name not in DESCRIPTORS:
        raise EstimatorError(f"unknown descriptor {name!r}; known: {', '.join(DESCRIPTORS)}")
    record = REGISTRY[name]
    given = {"lag": lag, "q": q, "dt": dt, "split": split, "threshold": threshold}
    for arg in record.batch_args:
        if given[arg] is None and arg in _OPTIONS:
            raise EstimatorError(f"{name} needs {_OPTIONS[arg]}")
    assert record.batch is not None
    return load(record.batch)(frames, **{arg: given[arg] for arg in record.batch_args})
