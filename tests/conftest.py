from __future__ import annotations

from pathlib import Path

import pytest

from tests.kernel_cache import ESTIMATORS, warm_start

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def repo() -> Path:
    return REPO


def pytest_collection_modifyitems(session: pytest.Session, config: pytest.Config, items: list[pytest.Item]) -> None:
    """Fill numba's disk cache before the first daemon process starts, when the daemon-process
    suites (integration, faults) run: on a fresh checkout a daemon's first start compiles its
    kernels (tens of seconds on 2 cores), longer than the tests wait for a daemon to answer; each
    later start loads them (tests/unit/daemon/test_warm_start.py). Here, outside any test's timeout."""
    if config.option.collectonly or not any({"integration", "faults"} & set(item.path.parts) for item in items):
        return
    for estimator in ESTIMATORS:
        warm_start(estimator)
