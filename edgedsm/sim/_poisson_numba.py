"""Compiled kernels of :mod:`edgedsm.sim.poisson` (the same expressions in the same order).

Importing this module imports numba (the optional extra ``fast``); :mod:`edgedsm.sim.poisson`
imports it lazily. ``fastmath`` stays off and ``error_model="numpy"`` makes x/0 = ±inf as in
numpy, so both kernels round identically. ``nogil``: the simulator runs blocks in threads.
"""

from __future__ import annotations

import math

import numba
import numpy as np

PTRS_MIN = 10.0


@numba.njit(cache=True, nogil=True, error_model="numpy")
def poisson_round(lam, uniforms, out, accept, log_factorial):  # pragma: no cover - compiled
    """One round for n pixels; see poisson_round_numpy. Returns the number rejected."""
    n = out.size
    constant = lam.size != n
    rejected = 0
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
            accept[j] = True
            continue
        U = uniforms[j] - 0.5
        V = uniforms[n + j]
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
        accept[j] = ok
        if ok:
            out[j] = k
        else:
            rejected += 1
    return rejected


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
