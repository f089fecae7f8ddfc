"""The daemon's kernels come from numba's disk cache at the next start (a defect of issue 13's
first region kernels, and of the τc lag-product kernels: closures over other compiled closures
got a new cache key in every process, so each start compiled them again, 7-10 s before the first
frame). Two real processes run the evaluation's warm-up on the same settings; the second must
compile nothing."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.kernel_cache import ESTIMATORS, warm_start


@pytest.mark.slow
@pytest.mark.parametrize("estimator", ESTIMATORS, ids=["default", "tumbling-tau", "sliding-tau", "exponential"])
def test_the_second_start_compiles_nothing(estimator: dict) -> None:
    warm_start(estimator)  # compiles what is not cached yet
    assert warm_start(estimator) == []


VARIANTS = r"""
import numpy as np
from edgedsm.estimators.kernels_numba import maps_kernel
n = 64
sums = [np.ones(n, np.int32)] * 5
out = [np.empty(n) for _ in range(7)]
for parallel in (False, True):  # the serial variant compiled (and cached) first, as the warm-up does
    kernel = maps_kernel(True, True, True, parallel)
    kernel(*sums, 3, 0.5, 4, *out, 1.0)
    print(kernel.stats.cache_hits.total(), kernel.targetoptions.get("parallel", False))
"""


@pytest.mark.slow
def test_parallel_and_serial_variants_are_cached_apart(tmp_path: Path) -> None:
    """numba's cache key leaves out the decorator's options: without kernel_variant the parallel
    kernel loaded the serial one's code from the cache (found: 4x slower region statistics)."""
    done = subprocess.run([sys.executable, "-c", VARIANTS], capture_output=True, text=True, timeout=240,
                          env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["0", "False", "0", "True"]  # each compiled, none loaded the other's code
