"""Which per-pixel values a set of maps needs, and GD from its exact sum: the light part of the
engine's map arithmetic (numpy only, no numba: the engine's modules import it at start, the
compiled formulas of :mod:`edgedsm.estimators.activity` load with the kernels).

- :func:`flags_of`: the flags of :func:`edgedsm.estimators.activity.pixel_values` for a set of
  map names (S3 needs S1's sum, Fujii is formed from S2); :data:`VALUES` and
  :func:`value_sizes`: the arrays the maps kernel writes.
- :func:`gd_of_sum`: the generalized differences (BSLTL's ``gendiff.m``) from their exact integer
  sum, written once for the batch reference (``descriptors.gd``), the engine's maps, snapshots
  and region statistics; :func:`gd_mode_problem`: the window modes that can keep that sum.
"""

from __future__ import annotations

import numpy as np

#: int64's largest value: N·Σ(I-k)² stays exact in int64 up to INT64_MAX // N.
INT64_MAX = 2**63 - 1

#: The per-pixel values ``activity.pixel_values`` forms, in its order (and the maps arrays' names).
VALUES = ("s1", "s2", "s3", "sigma", "contrast", "fujii", "im")


def flags_of(names: tuple[str, ...] | list[str] | set[str]) -> tuple[bool, bool, bool, bool, bool, bool]:
    """(do_abs, do_s2, do_s3, do_contrast, do_fujii, do_im) of ``activity.pixel_values`` for the maps
    ``names``: S3 needs S1's sum, Fujii is formed from S2."""
    wanted = set(names)
    return ("s1" in wanted or "s3" in wanted, "s2" in wanted or "fujii" in wanted, "s3" in wanted,
            "contrast" in wanted, "fujii" in wanted, "im" in wanted)


def value_sizes(flags: tuple[bool, ...], pixels: int) -> dict[str, int]:
    """Pixels of each array of :data:`VALUES` the maps kernel writes for ``flags`` (0: not formed)."""
    do_abs, do_s2, do_s3, do_contrast, do_fujii, do_im = flags
    formed = (do_abs, do_s2, do_s3, do_s3 or do_contrast, do_contrast, do_fujii, do_im)
    return {name: pixels if on else 0 for name, on in zip(VALUES, formed, strict=True)}


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
    """Why GD cannot stream in window ``mode`` (None: it can); the one statement of it (engine, config)."""
    if mode in ("sliding", "tumbling"):
        return None
    return (f"gd needs mode 'sliding' or 'tumbling', not {mode!r} (its exact sum reads the window's frames, and "
            f"the {mode} mode keeps none)")
