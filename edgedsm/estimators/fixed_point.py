"""Fixed-point S2 terms of the streaming engine (paper Eq. 2): how each |a-b|/(a+b+q) enters an
exact int64 sum, and the error bound that gives.

S2, sliding and tumbling: each term |a-b|/(a+b+q) enters an int64 sum as a fixed-point integer T with
  scale 2^K (:func:`ratio_scale_bits`; N-m terms stay below 2^63). Adding and removing use
  the same T, so the sum is an exact integer and never drifts. How T is formed
  (:func:`ratio_kind`):

  * ``exact`` (<= 8-bit data, integer q; K = min(51, 63 - bit_length(N-m))): T is |a-b|·2^K
    / (a+b+q) rounded half up, *exactly*: the float64 estimate fl(fl(|a-b|/d)·2^K) is within
    2^(K-53) <= 1/4 of the true value, so its rounding is off by at most one, and one
    integer test of the remainder, 0 <= 2(|a-b|·2^K - T·d) + d < 2d, corrects it. Branch-
    free and vectorised, and equal entry by entry to the table below (tested). The compiled
    kernels read these same values from the table (``TABLED_KINDS``): one gather from a 512 KiB
    table costs less than the division and its correction (docs/engine.md, "S2's term"); the
    formula stays for the NumPy twin and callers without a table, and the sums are the same
    integers either way (tested, sliding and tumbling).
  * ``lut`` (<= 8-bit data, fractional q; K = min(62, 63 - bit_length(N-m))): a 256 x 256
    table of the same exactly rounded values, computed once with rational arithmetic (a
    float q is an exact binary fraction).
  * ``float`` (9 to 16-bit data; K = min(51, 63 - bit_length(N-m))): y = fl(|a-b| /
    max(fl(a+b+q), 1))·2^K, and T is y rounded to the nearest integer (ties to even) by
    adding 2^52 and reading the integer off the float's bits: exact because 0 <= y < 2^52 (so
    K <= 51), cheaper than floor and a float-to-int conversion (docs/engine.md, "S2's term").
    Two relative roundings (<= u = 2^-53 each: fl(a+b+q), the quotient), so
    |T·2^-K - term| <= 2^-(K+1) + 3u·term. T <= 2^K + 1 (term <= 1), so N-m terms still fit
    an int64 (N-m < 2^31 <= 2^K).

  With the final conversion to float64 (two roundings, S2 <= 1 because |a-b| <= a+b+q)
  this gives the absolute bound :func:`s2_error_bound`::

      |S2_stream - S2_exact| <= 2^-(K+1) + 2^-51   (exact, lut: every term exactly rounded)
      |S2_stream - S2_exact| <= 2^-(K+1) + 6u      (float: 3u + 2u + O(u²) <= 6u)

  Checked against exact rational arithmetic (``fractions.Fraction``) on adversarial 12- and
  16-bit pairs: every denominator, the extreme differences (tests/unit/estimators).
  That is below 7e-16 for N = 200, m = 10 (K = 51, 8-bit, q = 0), and 8.9e-16 (8·2^-53) on 9
  to 16-bit data (K = 51; before the 2^52 rounding, K = 55 and a stated 2^-55 + 2^-50 =
  9.2e-16): closer to the exact value than the float64 batch sum itself, whose own error is
  up to ~(N-m)·u. Because nothing drifts, resynchronising from the ring
  (:meth:`SlidingWindow.resync`, ``resync_every``) reproduces the running sums bit for bit;
  it is offered as a guard against corrupted memory in month-long runs.
"""

from __future__ import annotations

import functools
from fractions import Fraction

import numpy as np

from edgedsm.errors import EstimatorError

_EXACT_MAX_Q = 2**40  # integer q up to this keeps a+b+q and T·(a+b+q) exact in the kernels


#: The S2 term kinds the compiled kernels read from :func:`ratio_lut` (8-bit data): the table
#: holds the exactly rounded terms, so "exact" and "lut" sums are those of the formula above.
TABLED_KINDS = ("exact", "lut")

_NO_LUT = np.zeros(0, np.int64)
_NO_LUT.setflags(write=False)

#: y + 2^52 (0 <= y < 2^52) is y rounded to an integer T, and its bits are ROUNDING_BITS + T.
ROUNDING = 2.0**52
ROUNDING_BITS = int(np.float64(ROUNDING).view(np.int64))


def ratio_kind(bits: int, q: float) -> str:
    """How S2 terms are formed: "exact", "lut" or "float" (see this module's docstring)."""
    if bits > 8:
        return "float"
    return "exact" if float(q).is_integer() and q <= _EXACT_MAX_Q else "lut"


def ratio_scale_bits(pairs: int, kind: str = "lut") -> int:
    """K of the S2 fixed point: the largest with pairs·2^K <= 2^63 - 1, and K <= 51 for the
    "exact" terms (their float64 estimate must be within 1/4 of the true value) and the
    "float" ones (their y must stay below 2^52 for the 2^52 rounding)."""
    if pairs < 1:
        raise EstimatorError(f"need at least one pair, got {pairs}")
    k = min(62, 63 - int(pairs).bit_length())
    return min(k, 51) if kind in ("exact", "float") else k


def s2_error_bound(pairs: int, bits: int, q: float = 0.0) -> float:
    """Absolute bound on |S2_stream - S2_exact| for N - m = ``pairs`` (see this module's docstring)."""
    kind = ratio_kind(bits, q)
    k = ratio_scale_bits(pairs, kind)
    if kind == "float":
        return 2.0 ** -(k + 1) + 6 * 2.0**-53
    return 2.0 ** -(k + 1) + 2.0**-51


@functools.lru_cache(maxsize=16)
def ratio_lut(q: float, scale_bits: int) -> np.ndarray:
    """Eq. 2 terms for 8-bit data in fixed point: entry (a << 8) | b = round(|a-b|/(a+b+q)·2^K).

    Computed with exact rational arithmetic (a float q is an exact binary fraction), rounded
    half up, so every entry is within 2^-(K+1) of the true term; 0 where a + b + q = 0.
    Read-only int64 array of 65536 entries (512 KiB), cached per (q, K).
    """
    q_exact = Fraction(q)
    q_num, q_den = q_exact.numerator, q_exact.denominator
    one = 1 << scale_bits
    table = np.zeros(256 * 256, np.int64)
    for a in range(256):
        for b in range(a, 256):
            # term·2^K = (b-a)·2^K·q_den / ((a+b)·q_den + q_num); round half up exactly
            numerator = (b - a) * one * q_den
            denominator = (a + b) * q_den + q_num
            value = (2 * numerator + denominator) // (2 * denominator) if denominator else 0
            table[(a << 8) | b] = value
            table[(b << 8) | a] = value
    table.setflags(write=False)
    return table
