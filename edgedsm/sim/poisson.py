"""Exact Poisson photon counts for the detector, drawn so that every pixel's uniforms sit at a
fixed place of the stream.

Per-pixel λ (:func:`poisson`, the shot noise of the laser signal):

* λ >= 10: PTRS, the transformed rejection with squeeze of Hörmann (1993) that
  ``numpy.random.Generator.poisson`` uses, with its constants. The final test
  log(V) + log(1/α) - log(a/us² + b) <= k·log λ - λ - log k! is evaluated with the three
  logarithms on the left merged into one and log k! looked up in a table (k < 65536).
* λ < 10: inversion, one uniform: the smallest k with u <= F(k), F summed from exp(-λ).

Draws are made in rounds: round 1 takes 2n uniforms of the stream for the n pixels at once,
pixel j using the j-th (and the (n+j)-th); the pixels PTRS rejects (~15 %) go to later rounds,
whose uniforms come from a counter-based generator (SplitMix64 at a position given by the pixel
and the round, keyed by one more draw of the stream). Every call thus takes exactly 2n + 1
draws and every pixel's uniforms are its own: a tiny change of λ (single against double
precision upstream, or a little phase noise) changes only the counts of the pixels whose own
draw it decides, instead of shifting every later draw as a sequential rejection sampler does.

Constant λ (:class:`ConstantPoisson`, the ambient light): Walker's alias method, one uniform
per pixel.

Kernels: a compiled loop with numba (the optional extra ``fast``, imported lazily), else numpy
array operations. Both evaluate the same expressions in the same order (no fastmath, no FMA
contraction) with the same tables, so they give the same counts; only ``exp``, ``log`` (and
lgamma for k >= 65536) come from different libraries, so a draw could differ where a
comparison is decided at the level of ~1e-16 (never seen in tests). With numba the shot noise
is ~2x and the ambient light ~5x faster than ``Generator.poisson``.
"""

from __future__ import annotations

from types import ModuleType
from typing import Literal

import numpy as np
from scipy.special import gammaln

Kernel = Literal["auto", "numba", "numpy"]
PTRS_MIN = 10.0  # numpy's threshold between the multiplication method and PTRS
LOG_FACTORIAL_SIZE = 1 << 16

_log_factorial: np.ndarray | None = None
_numba_module: ModuleType | bool | None = False  # False: not tried yet, None: unavailable


def _numba() -> ModuleType | None:
    """The compiled kernel module, imported on first use."""
    global _numba_module
    if _numba_module is False:
        try:
            from edgedsm.sim import _poisson_numba
        except ImportError:
            _numba_module = None
        else:
            _numba_module = _poisson_numba
    return _numba_module  # type: ignore[return-value]


def _kernel_module(kernel: Kernel) -> ModuleType | None:
    """numba's module, or None for the numpy kernel."""
    if kernel == "numpy":
        return None
    module = _numba()
    if module is None and kernel == "numba":
        raise ImportError("kernel='numba' needs numba (install the 'fast' extra: pip install 'edgedsm[fast]')")
    return module


def log_factorials() -> np.ndarray:
    """log(k!) for k < 2^16 (512 KiB), shared by both kernels."""
    global _log_factorial
    if _log_factorial is None:
        table = gammaln(np.arange(LOG_FACTORIAL_SIZE, dtype=np.float64) + 1.0)
        table.setflags(write=False)
        _log_factorial = table
    return _log_factorial


# -- numpy kernel ------------------------------------------------------------------------------
def _inversion_numpy(lam: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Smallest k with u <= F(k) for λ < 10 (see module docstring), vectorised."""
    p = np.exp(-lam)
    F = p.copy()
    k = np.zeros(lam.shape, np.float64)
    active = np.flatnonzero(u > F)
    step = 0.0
    while active.size:
        step += 1.0
        p_a = p[active] * (lam[active] / step)
        F_a = F[active]
        grown = F_a + p_a
        k[active] = step
        moving = grown != F_a  # F no longer grows: the far tail, stop there
        p[active], F[active] = p_a, grown
        active = active[moving & (u[active] > grown)]
    return k


def _ptrs_numpy(L, U, V, log_factorial: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """PTRS counts and acceptance for uniforms U (centred: U - 0.5) and V, λ = L >= 10."""
    us = 0.5 - np.abs(U)
    slam = np.sqrt(L)
    b = 0.931 + 2.53 * slam
    a = -0.059 + 0.02483 * b
    vr = 0.9277 - 3.6224 / (b - 2.0)
    with np.errstate(divide="ignore", invalid="ignore"):  # us = 0 when a uniform is exactly 0
        k = np.floor((2.0 * a / us + b) * U + L + 0.43)
    accept = (us >= 0.07) & (vr >= V)
    slow = np.flatnonzero(~accept & (k >= 0) & ~((us < 0.013) & (us < V)))
    if slow.size:
        us_s, V_s, k_s = us[slow], V[slow], k[slow]
        L_s, a_s, b_s = (L[slow], a[slow], b[slow]) if np.ndim(L) else (L, a, b)
        invalpha = 1.1239 + 1.1328 / (b_s - 3.4)
        with np.errstate(divide="ignore"):  # log(V = 0) = -inf: accepted, as in numpy
            lhs = np.log(V_s * invalpha / (a_s / (us_s * us_s) + b_s))
        in_table = k_s < log_factorial.size
        log_k_factorial = np.where(in_table, log_factorial[np.where(in_table, k_s, 0).astype(np.intp)],
                                   gammaln(k_s + 1.0))
        accept[slow] = lhs <= k_s * np.log(L_s) - L_s - log_k_factorial
    return k, accept


def poisson_round_numpy(lam: np.ndarray, uniforms: np.ndarray, out: np.ndarray, accept: np.ndarray,
                        log_factorial: np.ndarray) -> int:
    """One round for n pixels: accepted counts into ``out``, flags into ``accept``; #rejected.

    ``lam`` has n entries or one (the same λ for all); ``uniforms`` 2n numbers in [0, 1).
    """
    n = out.size
    U = uniforms[:n]
    V = uniforms[n:]
    if lam.size != n:
        value = float(lam[0])
        if value < PTRS_MIN:
            out[:] = _inversion_numpy(np.full(n, value), U)
            accept[:] = True
            return 0
        k, ok = _ptrs_numpy(value, U - 0.5, V, log_factorial)
        np.copyto(out, k, where=ok)
        accept[:] = ok
        return int(n - np.count_nonzero(ok))
    small = lam < PTRS_MIN
    if not small.any():
        k, ok = _ptrs_numpy(lam, U - 0.5, V, log_factorial)
        np.copyto(out, k, where=ok)
        accept[:] = ok
        return int(n - np.count_nonzero(ok))
    accept[:] = True
    index = np.flatnonzero(small)
    out[index] = _inversion_numpy(lam[index], U[index])
    index = np.flatnonzero(~small)
    if index.size:
        k, ok = _ptrs_numpy(lam[index], U[index] - 0.5, V[index], log_factorial)
        out[index[ok]] = k[ok]
        accept[index] = ok
    return int(n - np.count_nonzero(accept))


# -- drivers -----------------------------------------------------------------------------------
def poisson(rng: np.random.Generator, lam: float | np.ndarray, shape: tuple[int, ...] | None = None,
            kernel: Kernel = "auto") -> np.ndarray:
    """Poisson(λ) counts as float64: ``lam`` an array (its shape) or a number (with ``shape``).

    Takes exactly 2n + 1 draws of ``rng`` for n counts, whatever the rejections.
    """
    if np.ndim(lam) == 0:
        if shape is None:
            raise ValueError("a constant λ needs a shape")
        rates = np.array([float(lam)])  # type: ignore[arg-type]
        out = np.empty(shape, np.float64)
    else:
        rates = np.ascontiguousarray(lam, np.float64).reshape(-1)
        out = np.empty(np.shape(lam), np.float64)
    if rates.size and not (rates.min() >= 0 and np.isfinite(rates.max())):  # NaN fails both
        raise ValueError("λ must be finite and >= 0")
    flat = out.reshape(-1)
    if flat.size == 0:
        return out
    uniforms = rng.random(2 * flat.size)
    key = np.uint64(rng.bit_generator.random_raw())
    module = _kernel_module(kernel)
    if module is None:
        _rounds_numpy(rates, uniforms, key, flat, log_factorials())
    else:
        module.poisson_pixels(rates, uniforms, key, flat, log_factorials())
    return out


_GAMMA = np.uint64(0x9E3779B97F4A7C15)  # SplitMix64's increment (golden ratio)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)


def counter_uniforms(key: np.uint64, counters: np.ndarray) -> np.ndarray:
    """SplitMix64 at the given positions of the sequence seeded by ``key``: uniforms in [0, 1).

    A counter-based generator: the value at a position does not depend on which other
    positions are asked for, so a pixel's later-round uniforms are its own.
    """
    z = counters.astype(np.uint64) * _GAMMA + key  # wraps modulo 2^64, as intended
    z = (z ^ (z >> np.uint64(30))) * _MIX1
    z = (z ^ (z >> np.uint64(27))) * _MIX2
    z ^= z >> np.uint64(31)
    return (z >> np.uint64(11)).astype(np.float64) * 2.0**-53


def _rounds_numpy(lam: np.ndarray, uniforms: np.ndarray, key: np.uint64, out: np.ndarray,
                  log_factorial: np.ndarray) -> None:
    """Round 1 with ``uniforms``; the PTRS rejects then retry, round r >= 2 of pixel j using the
    counter-based uniforms at positions ((r-2)·n + j)·2 (U) and +1 (V)."""
    n = out.size
    accept = np.empty(n, np.bool_)
    if not poisson_round_numpy(lam, uniforms, out, accept, log_factorial):
        return
    constant = lam.size != n
    pending = np.flatnonzero(~accept)
    later = 0
    while pending.size:
        base = (np.uint64(later) * np.uint64(n) + pending.astype(np.uint64)) * np.uint64(2)
        retry = np.concatenate([counter_uniforms(key, base), counter_uniforms(key, base + np.uint64(1))])
        m = pending.size
        counts = np.empty(m, np.float64)
        ok = np.empty(m, np.bool_)
        poisson_round_numpy(lam if constant else lam[pending], retry, counts, ok, log_factorial)
        out[pending[ok]] = counts[ok]
        pending = pending[~ok]
        later += 1


class ConstantPoisson:
    """Poisson(λ) for one λ shared by every pixel (the ambient light): Walker's alias method.

    The table holds the pmf over [λ - w, λ + w], w = 12·sqrt(λ) + 30 (the mass left out is
    < 1e-25); a draw is one uniform u: column j = floor(u·size), kept if the fraction of u·size
    is below threshold[j], else its alias. λ < 10 or a table over 65536 entries (λ > ~7e6):
    :func:`poisson`.
    """

    MAX_TABLE = 1 << 16

    def __init__(self, lam: float, kernel: Kernel = "auto") -> None:
        lam = float(lam)
        if not np.isfinite(lam) or lam < 0:
            raise ValueError(f"λ must be finite and >= 0, got {lam}")
        self.lam = lam
        self.kernel = kernel
        width = 12.0 * np.sqrt(lam) + 30.0
        offset = int(max(0.0, np.floor(lam - width)))
        size = int(np.ceil(lam + width)) + 1 - offset
        self.table: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        if lam >= PTRS_MIN and size <= self.MAX_TABLE:
            threshold, alias = _alias_table(_poisson_pmf(lam, offset, size))
            values = np.arange(offset, offset + size, dtype=np.float64)
            self.table = (threshold, values, values[alias])

    def draw(self, rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        """Counts of ``shape`` as float64."""
        if self.table is None:
            return poisson(rng, self.lam, shape, self.kernel)
        threshold, self_value, alias_value = self.table
        uniforms = rng.random(shape)
        module = _kernel_module(self.kernel)
        if module is not None:
            out = np.empty(shape, np.float64)
            module.alias_draw(uniforms.reshape(-1), threshold, self_value, alias_value, out.reshape(-1))
            return out
        x = uniforms
        x *= threshold.size
        column = x.astype(np.intp)  # floor, as x >= 0
        x -= column  # the fraction decides between the column and its alias
        return np.where(x < threshold[column], self_value[column], alias_value[column])


def _poisson_pmf(lam: float, offset: int, size: int) -> np.ndarray:
    """pmf of Poisson(λ) at offset..offset+size-1, normalised to sum 1."""
    k = np.arange(offset, offset + size, dtype=np.float64)
    pmf = np.exp(k * np.log(lam) - lam - gammaln(k + 1.0))
    return pmf / pmf.sum()


def _alias_table(pmf: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vose's alias table: column j gives j with probability threshold[j], else alias[j]."""
    size = pmf.size
    scaled = pmf * size
    threshold = np.ones(size, np.float64)
    alias = np.arange(size, dtype=np.intp)
    small = [j for j in range(size) if scaled[j] < 1.0]
    large = [j for j in range(size) if scaled[j] >= 1.0]
    while small and large:
        j, g = small.pop(), large.pop()
        threshold[j], alias[j] = scaled[j], g
        scaled[g] -= 1.0 - scaled[j]
        (small if scaled[g] < 1.0 else large).append(g)
    # the columns left over hold 1 up to rounding: they keep themselves (threshold 1)
    return threshold, alias
