"""Compiled kernels of :mod:`edgedsm.sim.poisson` (the same expressions in the same order).

Importing this module imports numba (the optional extra ``fast``); :mod:`edgedsm.sim.poisson`
imports it lazily. ``fastmath`` stays off and ``error_model="numpy"`` makes x/0 = ±inf as in
numpy, so both kernels round identically; integer arithmetic is kept in uint64 throughout.
``nogil``: the simulator runs blocks in threads.
"""

from __future__ import annotations

import math

import numba
import numpy as np

PTRS_MIN = 10.0
_GAMMA = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)


@numba.njit(cache=True, nogil=True, inline="always")
def _counter_uniform(key, counter):  # pragma: no cover - compiled
    """counter_uniforms for one position."""
    z = counter * _GAMMA + key
    z = (z ^ (z >> _S30)) * _MIX1
    z = (z ^ (z >> _S27)) * _MIX2
    z = z ^ (z >> _S31)
    return np.float64(z >> _S11) * 2.0**-53


@numba.njit(cache=True, nogil=True, error_model="numpy", inline="always")
def _ptrs(L, U, V, log_factorial):  # pragma: no cover - compiled
    """One PTRS attempt (U centred: uniform - 0.5): (k, accepted); see _ptrs_numpy."""
    us = 0.5 - abs(U)
    slam = math.sqrt(L)
    b = 0.931 + 2.53 * slam
    a = -0.059 + 0.02483 * b
    vr = 0.9277 - 3.6224 / (b - 2.0)
    k = np.floor((2.0 * a / us + b) * U + L + 0.43)  # float: -inf when us = 0
    ok = us >= 0.07 and vr >= V
    if not ok and k >= 0 and not (us < 0.013 and us < V):
        invalpha = 1.1239 + 1.1328 / (b - 3.4)
        lhs = np.log(V * invalpha / (a / (us * us) + b))
        log_k_factorial = log_factorial[int(k)] if k < log_factorial.size else math.lgamma(k + 1.0)
        ok = lhs <= k * np.log(L) - L - log_k_factorial
    return k, ok


@numba.njit(cache=True, nogil=True, error_model="numpy")
def poisson_pixels(lam, uniforms, key, out, log_factorial):  # pragma: no cover - compiled
    """All rounds of every pixel; see poisson_round_numpy and _rounds_numpy."""
    n = out.size
    constant = lam.size != n
    for j in range(n):
        L = lam[0] if constant else lam[j]
        if L < PTRS_MIN:  # inversion with the first uniform
            u = uniforms[j]
            p = np.exp(-L)
            F = p
            k = 0.0
            step = 0.0
            while u > F:
                step += 1.0
                p = p * (L / step)
                grown = F + p
                k = step
                if grown == F:  # F no longer grows: the far tail, stop there
                    break
                F = grown
            out[j] = k
            continue
        k, ok = _ptrs(L, uniforms[j] - 0.5, uniforms[n + j], log_factorial)
        later = np.uint64(0)
        while not ok:
            counter = (later * np.uint64(n) + np.uint64(j)) * np.uint64(2)
            U = _counter_uniform(key, counter) - 0.5
            V = _counter_uniform(key, counter + np.uint64(1))
            k, ok = _ptrs(L, U, V, log_factorial)
            later += np.uint64(1)
        out[j] = k


@numba.njit(cache=True, nogil=True)
def alias_draw(uniforms, threshold, self_value, alias_value, out):  # pragma: no cover - compiled
    """Walker alias lookup; see ConstantPoisson.draw (the same float operations)."""
    size = threshold.size
    for j in range(uniforms.size):
        x = uniforms[j] * size
        column = int(x)
        if x - column < threshold[column]:
            out[j] = self_value[column]
        else:
            out[j] = alias_value[column]
