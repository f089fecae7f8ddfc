"""S2's fixed-point terms on 9 to 16-bit data (the "float" kind of edgedsm.estimators.fixed_point)
against exact rational arithmetic: the stated per-term bound on adversarial pairs, and the S2
bound of whole windows."""

from __future__ import annotations

import importlib
import importlib.util
from fractions import Fraction

import numpy as np
import pytest

from edgedsm.estimators import SlidingWindow
from edgedsm.estimators.fixed_point import _NO_LUT, ratio_kind, ratio_scale_bits, s2_error_bound

KERNELS = ["numpy"] + (["numba"] if importlib.util.find_spec("numba") else [])


def adversarial_pairs(bits: int) -> tuple[np.ndarray, np.ndarray]:
    """Every denominator a + b (0 .. 2·top), each with its largest and its smallest difference
    (one value at 0 or full scale; a = b or |a-b| = 1), and full scale against every value."""
    top = (1 << bits) - 1
    s = np.arange(2 * top + 1)
    far_a = np.maximum(s - top, 0)
    near_a = s // 2
    every = np.arange(top + 1)
    a = np.concatenate([far_a, near_a, every, np.full(top + 1, top)])
    b = np.concatenate([s - far_a, s - near_a, np.zeros(top + 1, np.int64), every])
    return a.astype(np.uint16), b.astype(np.uint16)


def terms(kernel: str, kind: str, first: np.ndarray, second: np.ndarray, q: float, k: int) -> np.ndarray:
    """The fixed-point terms T(a, b) the engine's kernels add (the resync pass adds one pair)."""
    module = importlib.import_module(f"edgedsm.estimators.kernels_{kernel}")
    ratio = np.zeros(first.size, np.int64)
    module.pairs_kernel(False, True, kind, True)(first, second, np.zeros(0, np.int64), ratio, np.zeros(0, np.int64),
                                                 _NO_LUT, float(2**k), q)
    return ratio


@pytest.mark.parametrize("q", [0.0, 1.0, 0.1, 1000.5])
@pytest.mark.parametrize(("bits", "pairs"), [(12, 190), (16, 190), (10, 5000), (14, 190)])
def test_terms_are_within_the_stated_bound_of_the_rational_term(bits, pairs, q):
    """|T·2^-K - term| <= 2^-(K+1) + 3u·term for every denominator and the extreme differences,
    checked in exact integer arithmetic (q as an exact Fraction); numba and NumPy give the same T."""
    kind = ratio_kind(bits, q)
    assert kind == "float"
    k = ratio_scale_bits(pairs, kind)
    assert k == min(51, 63 - pairs.bit_length())
    a, b = adversarial_pairs(bits)
    got = {kernel: terms(kernel, kind, a, b, q, k) for kernel in KERNELS}
    for kernel in KERNELS[1:]:
        np.testing.assert_array_equal(got[kernel], got[KERNELS[0]])
    q_exact = Fraction(q)
    q_num, q_den = q_exact.numerator, q_exact.denominator
    one = 1 << k
    for x, y, t in zip(a.tolist(), b.tolist(), got[KERNELS[0]].tolist(), strict=True):
        assert 0 <= t <= one + 1  # N-m terms fit the int64 sum (fixed_point's docstring)
        if x + y + q_exact == 0:
            assert t == 0
            continue
        # term = N/D; |T - 2^K·N/D| <= 1/2 + 3·2^-53·2^K·N/D, times 2^53·D (all integers)
        numerator, denominator = abs(x - y) * q_den, (x + y) * q_den + q_num
        assert abs(t * denominator - numerator * one) << 53 <= (denominator << 52) + 3 * numerator * one, (x, y)


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("bits", [12, 16])
@pytest.mark.parametrize("q", [0.0, 1.0, 0.1])
def test_sliding_s2_of_adversarial_frames_is_within_the_bound(kernel, bits, q):
    """Dark, saturated, 0/full-scale alternating, ±1 and random pixels through a sliding window
    long enough to add and remove: S2 within s2_error_bound of the rational S2, and the sums equal
    those rebuilt from the window (adding and removing the same T: no drift)."""
    top = (1 << bits) - 1
    window, lag, count = 12, 3, 40
    rng = np.random.default_rng(bits)
    frames = rng.integers(0, top + 1, (count, 3, 4)).astype(np.uint16)
    frames[:, 0, 0] = 0
    frames[:, 0, 1] = top
    frames[:, 0, 2] = np.where(np.arange(count) % 2, top, 0)
    frames[:, 0, 3] = np.where(np.arange(count) % 2, top, top - 1)
    frames[:, 1, 0] = np.where(np.arange(count) % 3, 1, 0)
    engine = SlidingWindow((3, 4), window, lag, q=q, bits=bits, estimators=("s2",), kernel=kernel)
    for frame in frames:
        engine.push(frame)
    bound = s2_error_bound(window - lag, bits, q)
    assert engine.s2_bound == bound == 2.0**-52 + 6 * 2.0**-53 < 1e-15
    last = frames[-window:].reshape(window, -1).astype(int)
    q_exact = Fraction(q)
    for p, value in enumerate(engine.maps()["s2"].ravel().tolist()):
        pairs = zip(last[:-lag, p].tolist(), last[lag:, p].tolist(), strict=True)
        exact = sum((Fraction(abs(x - y)) / (x + y + q_exact) for x, y in pairs if x + y + q_exact),
                    Fraction(0)) / (window - lag)
        assert abs(Fraction(value) - exact) <= Fraction(bound), (p, value, float(exact))
    running = engine._arrays["ratio"].copy()
    engine.resync()
    np.testing.assert_array_equal(engine._arrays["ratio"], running)
