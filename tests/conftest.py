from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.kernel_cache import ESTIMATORS, warm_start

REPO = Path(__file__).resolve().parents[1]

#: Fixtures that start Aravis' fake GigE Vision camera: it answers on 127.0.0.1's GVCP port 3956,
#: one at a time, and cannot take another loopback address (it listens only on an address of a
#: network interface, and lo has just 127.0.0.1), so their tests run on one pytest-xdist worker.
FAKE_GIGE_FIXTURES = {"gv_factory", "fake_gige"}

#: The slow unit tests compute for long, many on every core (numba kernels, benchmarks' quick runs,
#: million-frame streams, kernel compilations): on one worker, one at a time, so that they never
#: take both cores from the daemons and brokers whose timing other workers' tests check.
CPU_BOUND_GROUP = "cpu_bound"


@pytest.fixture
def repo() -> Path:
    return REPO


def warm_daemon_kernels(paths: list[str]) -> None:
    """Fill numba's disk cache before the first daemon process starts, when the daemon-process
    suites (integration, faults) run: on a fresh checkout a daemon's first start compiles its
    kernels (tens of seconds on 2 cores), longer than the tests wait for a daemon to answer; each
    later start loads them (tests/unit/test_warm_start.py). Here, outside any test's timeout."""
    if any({"integration", "faults"} & set(Path(path).parts) for path in paths):
        for estimator in ESTIMATORS:
            warm_start(estimator)


@pytest.hookimpl(wrapper=True)
def pytest_collection_modifyitems(session: pytest.Session, config: pytest.Config,
                                  items: list[pytest.Item]) -> Iterator[None]:
    for item in items:  # before pytest-xdist reads the marks (inside the yield)
        if FAKE_GIGE_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.xdist_group("fake_gige"))
        if item.get_closest_marker("slow") and "unit" in item.path.parts:
            item.add_marker(pytest.mark.xdist_group(CPU_BOUND_GROUP))
    yield
    if getattr(config.option, "loadgroup", False):
        keep_xdist_groups(items)
    # Under pytest-xdist the controller warms the cache once, before it hands out any test
    # (pytest_xdist_node_collection_finished); the workers do not race to compile the same kernels.
    if not config.option.collectonly and "PYTEST_XDIST_WORKER" not in os.environ:
        warm_daemon_kernels([str(item.path) for item in items])


def keep_xdist_groups(items: list[pytest.Item]) -> None:
    """Give a grouped test the node id suffix "@group" that pytest-xdist's loadgroup scheduler goes
    by, where pytest-xdist could not: it writes ``item._nodeid``, which pytest 9.2 no longer reads
    (pytest-xdist issue #1386), and the groups were silently ignored. Nothing to do where it worked."""
    for item in items:
        names = sorted({str(mark.args[0] if mark.args else mark.kwargs.get("name", "default"))
                        for mark in item.iter_markers("xdist_group")})
        suffix = "@" + "_".join(names)
        if names and not item.nodeid.endswith(suffix):
            from _pytest.nodeid import NodeId  # pytest >= 9.2 (before it, the suffix is there)

            item._id = NodeId.parse(item.nodeid + suffix)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_node_collection_finished(node, ids: list[str]) -> None:
    config = node.config
    if config.option.collectonly or config.stash.get(_WARMED, False):
        return
    config.stash[_WARMED] = True
    warm_daemon_kernels([nodeid.split("::")[0] for nodeid in ids])


_WARMED = pytest.StashKey[bool]()
