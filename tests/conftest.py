from __future__ import annotations

from pathlib import Path

import pytest

from tests.kernel_cache import ESTIMATORS, warm_start

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def repo() -> Path:
    return REPO


@pytest.fixture(scope="session")
def compiled_kernels() -> None:
    """Fill numba's disk cache once, before the first daemon process starts: on a fresh checkout
    a daemon's first start compiles its kernels (tens of seconds on 2 cores), longer than the
    tests wait for a daemon to answer; each later start loads them (tests/unit/test_warm_start.py).
    The daemon-process suites (integration, faults) use it."""
    for estimator in ESTIMATORS:
        warm_start(estimator)
