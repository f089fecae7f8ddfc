"""Band power maps (edgedsm.estimators.bands): Parseval, tones in the right band, Hz with Δt."""

from __future__ import annotations

import numpy as np
import pytest

from edgedsm.errors import EstimatorError
from edgedsm.estimators import temporal_sigma
from edgedsm.estimators.bands import band_power, frequencies, ratio, split_powers


def _tones(n: int, cycles: list[float], amplitudes: list[float]) -> np.ndarray:
    """A (n, 1, len) stack: pixel p is 100 + a_p cos(2π c_p k / n), c_p cycles per record."""
    k = np.arange(n)[:, None]
    values = 100 + np.array(amplitudes) * np.cos(2 * np.pi * np.array(cycles) * k / n)
    return values[:, None, :]


@pytest.mark.parametrize("n", [16, 17, 64])
def test_the_bands_sum_to_the_variance(n: int) -> None:
    stack = np.random.default_rng(2).integers(0, 4096, (n, 3, 4)).astype(np.uint16)
    low, high = split_powers(stack)
    np.testing.assert_allclose(low + high, temporal_sigma(stack) ** 2, rtol=1e-12)


def test_a_tone_falls_in_its_band_in_hz() -> None:
    # 64 frames at 50 Hz: resolution 50/64 Hz; 8 cycles = 6.25 Hz, 24 cycles = 18.75 Hz
    stack = _tones(64, [8, 24], [10.0, 4.0])
    power = band_power(stack, [(0, 10), (10, 25)], dt=0.02)
    # a cosine of amplitude a has variance a²/2, all of it in its bin
    np.testing.assert_allclose(power[:, 0], [[50.0, 0.0], [0.0, 8.0]], atol=1e-10)
    assert frequencies(64, 0.02)[-1] == pytest.approx(25.0)
    low, high = split_powers(stack, dt=0.02, split=10.0)
    np.testing.assert_allclose(low[0], [50.0, 0.0], atol=1e-10)
    np.testing.assert_allclose(high[0], [0.0, 8.0], atol=1e-10)


def test_nyquist_belongs_to_the_top_band() -> None:
    stack = _tones(8, [4], [3.0])  # alternating ±3: all power at f = 0.5 cycles per frame
    low, high = split_powers(stack)
    assert high[0, 0] == pytest.approx(9.0, rel=1e-14) and low[0, 0] == pytest.approx(0.0, abs=1e-12)


def test_ratio_is_high_over_low_and_zero_without_low_power() -> None:
    low = np.array([2.0, 0.0, 0.0])
    high = np.array([3.0, 0.0, 5.0])
    np.testing.assert_array_equal(ratio(low, high), [1.5, 0.0, 0.0])
    np.testing.assert_array_equal(ratio(low, high, q=1.0), [1.0, 0.0, 5.0])


def test_bad_bands_are_refused() -> None:
    stack = np.zeros((8, 2, 2), np.uint8)
    with pytest.raises(EstimatorError, match="lo < hi"):
        band_power(stack, [(3, 1)])
    with pytest.raises(EstimatorError, match="Nyquist"):
        band_power(stack, [(30, 40)], dt=0.02)
    with pytest.raises(EstimatorError, match="split"):
        split_powers(stack, dt=0.02, split=25)
    with pytest.raises(EstimatorError, match="dt"):
        split_powers(stack, dt=0)
