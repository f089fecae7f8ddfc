"""The daemon's kernels come from numba's disk cache at the next start (a defect of issue 13's
first region kernels, and of the τc lag-product kernels: closures over other compiled closures
got a new cache key in every process, so each start compiled them again, 7-10 s before the first
frame). Two real processes run the evaluation's warm-up on the same settings; the second must
compile nothing."""

from __future__ import annotations

import pytest

from tests.kernel_cache import ESTIMATORS, warm_start


@pytest.mark.slow
@pytest.mark.parametrize("estimator", ESTIMATORS, ids=["default", "tumbling-tau", "sliding-tau", "exponential"])
def test_the_second_start_compiles_nothing(estimator: dict) -> None:
    warm_start(estimator)  # compiles what is not cached yet
    assert warm_start(estimator) == []
