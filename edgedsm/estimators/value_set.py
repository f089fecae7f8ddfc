"""Which per-pixel values a set of maps needs, and GD from its exact sum: the light part of the
engine's map arithmetic (numpy only, no numba: the engine's modules import it at start, the
compiled formulas of :mod:`edgedsm.estimators.activity` load with the kernels).

- :func:`flags_of` and :func:`value_sizes`: thin wrappers of the registry's
  :class:`~edgedsm.estimators.registry.KernelSpec` (which values the fused maps pass forms for a
  set of maps; S3 needs S1's sum, Fujii is formed from S2), kept for callers of the tuple form;
  :data:`VALUES`: the arrays the maps kernel writes (the registry's).
- :func:`gd_of_sum`: the generalized differences (BSLTL's ``gendiff.m``) from their exact integer
  sum, written once for the batch reference (``descriptors.gd``), the engine's maps, snapshots
  and region statistics; :func:`gd_mode_problem`: the window modes that can keep that sum (the
  registry's statement).
"""

from __future__ import annotations

import numpy as np

from edgedsm.estimators.registry import PAIR_SUM, VALUES, KernelSpec, mode_problem

#: int64's largest value: N·Σ(I-k)² stays exact in int64 up to INT64_MAX // N.
INT64_MAX = 2**63 - 1

__all__ = ["INT64_MAX", "VALUES", "KernelSpec", "flags_of", "gd_mode_problem", "gd_of_sum", "value_sizes",
           "window_spreads"]


def flags_of(names: tuple[str, ...] | list[str] | set[str]) -> tuple[bool, bool, bool, bool, bool, bool]:
    """(do_abs, do_s2, do_s3, do_contrast, do_fujii, do_im): ``KernelSpec.of(names).flags``, the
    positional form of the named spec."""
    return KernelSpec.of(names).flags


def value_sizes(flags: tuple[bool, ...] | KernelSpec, pixels: int) -> dict[str, int]:
    """Pixels of each array of :data:`VALUES` the maps kernel writes for ``flags`` (0: not formed)."""
    spec = flags if isinstance(flags, KernelSpec) else KernelSpec(*flags)
    return spec.sizes(pixels)


def window_spreads(total: np.ndarray, total_sq: np.ndarray, n: int) -> np.ndarray:
    """N²σ² = N·ΣI² - (ΣI)² of every pixel from the exact sums over N = ``n`` frames (grey
    levels², new float64 array; σ of Eq. 4 is its root over N): with k the nearest integer to the
    mean and r = ΣI - kN, N·Σ(I-k)² - r², every term an exact integer while N·Σ(I-k)² fits int64
    (else that product in float64, as ``activity.centred_spread``)."""
    s = total.astype(np.int64)
    k = np.floor(s.astype(np.float64) / n + 0.5).astype(np.int64)
    r = s - k * n
    centred = total_sq.astype(np.int64) - k * (s + r)  # Σ(I-k)² >= 0, exact
    fits = centred <= INT64_MAX // n
    spread = (n * np.where(fits, centred, 0) - r * r).astype(np.float64)
    if not fits.all():
        wide = ~fits
        spread[wide] = n * centred[wide].astype(np.float64) - (r[wide] * r[wide]).astype(np.float64)
    return spread


def gd_of_sum(gd_sum: np.ndarray, n: int, out: np.ndarray | None = None) -> np.ndarray:
    """Generalized differences, BSLTL ``gendiff.m``: Σ_{i<j} |I_i - I_j| / C(N, 2) over N = ``n``
    frames, grey levels: the exact integer sum Σ_{i<j} |I_i - I_j| divided once (each int64 made
    float64, then one division). A new array, or written into the float64 ``out``."""
    return np.divide(gd_sum.astype(np.float64), n * (n - 1) / 2, out=out)


def gd_mode_problem(mode: str) -> str | None:
    """Why GD cannot stream in window ``mode`` (None: it can): the registry's one statement."""
    return mode_problem(PAIR_SUM, mode)


#: The maps kernel's positional arguments before the named spec (kernels' ``maps_kernel``).
_LEGACY_MAPS_ARGS = ("do_abs", "do_ratio", "do_s3", "parallel", "exponential", "do_contrast", "do_fujii", "do_im")


def maps_kernel_args(spec: KernelSpec | bool, *args: bool, **options: bool) -> tuple[KernelSpec, bool, bool]:
    """(spec, parallel, exponential) of a ``maps_kernel(spec, parallel=True, exponential=False)``
    call, or of the positional booleans of earlier callers, ``maps_kernel(do_abs, do_ratio, do_s3,
    parallel, exponential, do_contrast, do_fujii, do_im)``."""
    if isinstance(spec, KernelSpec):
        given = {"parallel": True, "exponential": False,
                 **dict(zip(("parallel", "exponential"), args, strict=False)), **options}
        return spec, bool(given["parallel"]), bool(given["exponential"])
    given = {"parallel": True, "exponential": False, "do_contrast": False, "do_fujii": False, "do_im": False,
             **dict(zip(_LEGACY_MAPS_ARGS, (spec, *args), strict=False)), **options}
    flags = (given[name] for name in ("do_abs", "do_ratio", "do_s3", "do_contrast", "do_fujii", "do_im"))
    return KernelSpec(*map(bool, flags)), bool(given["parallel"]), bool(given["exponential"])
