"""THSP, co-occurrence matrix, IM and AVD (edgedsm.estimators.thsp) against coom.m's loop and the
per-pixel maps they summarise."""

from __future__ import annotations

import numpy as np
import pytest

from edgedsm.errors import EstimatorError
from edgedsm.estimators import s1
from edgedsm.estimators.descriptors import im
from edgedsm.estimators.thsp import avd, coom, inertia_moment, thsp


def _stack() -> np.ndarray:
    return np.random.default_rng(8).integers(0, 256, (20, 7, 9)).astype(np.uint8)


def test_thsp_of_a_row_and_of_a_column() -> None:
    stack = _stack()
    line = thsp(stack, row=3)
    assert line.shape == (9, 20) and line.dtype == np.float64
    np.testing.assert_array_equal(line[4], stack[:, 3, 4])
    column = thsp(stack, column=8)
    assert column.shape == (7, 20)
    np.testing.assert_array_equal(column[6], stack[:, 6, 8])


def test_coom_counts_transitions_as_bsltl_loop() -> None:
    image = thsp(_stack(), row=2)
    expected = np.zeros((256, 256), np.int64)
    for pixel in image:
        for k in range(len(pixel) - 1):
            expected[int(pixel[k]), int(pixel[k + 1])] += 1
    com = coom(image)
    np.testing.assert_array_equal(com, expected)
    assert com.sum() == 9 * 19


def test_coom_rounds_halves_up_and_clips() -> None:
    image = np.array([[0.5, 1.5, 2.49, 300.0, 255.5]])
    com = coom(image)
    # round: 1, 2, 2, 255 (clipped), 255 (256 clipped)
    assert {(int(a), int(b)) for a, b in zip(*np.nonzero(com), strict=True)} == {(1, 2), (2, 2), (2, 255), (255, 255)}


def test_im_and_avd_of_the_com_are_the_line_means_of_im_and_s1() -> None:
    stack = _stack()
    com = coom(thsp(stack, row=5))
    # same exact integer sums, one division each
    assert inertia_moment(com) == pytest.approx(im(stack, 1)[5].mean(), rel=1e-15)
    assert avd(com) == pytest.approx(s1(stack, 1)[5].mean(), rel=1e-15)


def test_known_com_moments() -> None:
    com = np.zeros((256, 256), np.int64)
    com[10, 13] = 2  # |d| = 3 twice
    com[7, 7] = 1  # d = 0
    com[0, 255] = 1  # |d| = 255
    assert avd(com) == (2 * 3 + 255) / 4
    assert inertia_moment(com) == (2 * 9 + 255**2) / 4


def test_bad_arguments_are_refused() -> None:
    stack = _stack()
    with pytest.raises(EstimatorError, match=r"row 7 is outside the 7 rows 0\.\.6"):
        thsp(stack, row=7)
    with pytest.raises(EstimatorError, match="column -1"):
        thsp(stack, column=-1)
    with pytest.raises(EstimatorError, match="exactly one"):
        thsp(stack)
    with pytest.raises(EstimatorError, match="empty"):
        avd(np.zeros((256, 256), np.int64))
    with pytest.raises(EstimatorError, match="256 x 256"):
        inertia_moment(np.ones((4, 4), np.int64))
