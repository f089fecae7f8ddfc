from __future__ import annotations

import contextlib
import fcntl
import os
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
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

#: Tests that only compute (estimators, tuning, reports, the simulator, the slow unit tests): no
#: daemon, broker, camera or wall-clock bound, so a test beside them taking the cores only makes
#: them wait. Marked ``compute``: ./scripts/test.sh runs them at idle priority beside the ``alone``
#: tests, on the cores those leave idle while they wait on timers, and the rest after.
COMPUTE_PATHS = ("tests/unit/estimators/", "tests/unit/tuning/", "tests/unit/report/", "tests/unit/sim/",
                 "tests/unit/test_timeline")


def slow_unit(item: pytest.Item) -> bool:
    """A unit test marked ``slow`` (a long computation, often on every core)."""
    return item.get_closest_marker("slow") is not None and "unit" in item.path.relative_to(REPO).parts


def computes_only(item: pytest.Item) -> bool:
    return item.get_closest_marker("alone") is None and (
        item.path.relative_to(REPO).as_posix().startswith(COMPUTE_PATHS) or slow_unit(item))


@pytest.fixture
def repo() -> Path:
    return REPO


def warm_daemon_kernels(paths: list[str]) -> None:
    """Fill numba's disk cache before the first daemon process starts, when the daemon-process
    suites (integration, faults) run: on a fresh checkout a daemon's first start compiles its
    kernels (tens of seconds on 2 cores), longer than the tests wait for a daemon to answer; each
    later start loads them (tests/unit/daemon/test_warm_start.py). Here, outside any test's timeout,
    one process per estimator setting at once: the kernels they share are compiled once
    (edgedsm.estimators.jit.compile_once), the others on both cores."""
    if any({"integration", "faults"} & set(Path(path).parts) for path in paths):
        with ThreadPoolExecutor(len(ESTIMATORS)) as pool:
            list(pool.map(lambda case: warm_start(*case), ESTIMATORS))


def pytest_report_header(config: pytest.Config) -> list[str]:
    """Which versions this run ran, and whether they are requirements/test.lock's (tests/locks.py)."""
    from tests.locks import report_lines
    return report_lines()


@pytest.hookimpl(wrapper=True)
def pytest_collection_modifyitems(session: pytest.Session, config: pytest.Config,
                                  items: list[pytest.Item]) -> Iterator[None]:
    for item in items:  # before pytest-xdist reads the marks (inside the yield)
        if FAKE_GIGE_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.xdist_group("fake_gige"))
        if slow_unit(item):
            item.add_marker(pytest.mark.xdist_group(CPU_BOUND_GROUP))
        if computes_only(item):
            item.add_marker(pytest.mark.compute)
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


@contextlib.contextmanager
def turn(directory: Path, alone: bool) -> Iterator[None]:
    """One test's turn among pytest-xdist's workers: shared, or ``alone`` (after the tests running
    now, with the other workers waiting before their next one). A gate lock first, so that tests
    waiting to run alone are not kept waiting by a stream of shared ones."""
    with (directory / "gate").open("a") as gate, (directory / "turn").open("a") as lock:
        fcntl.flock(gate, fcntl.LOCK_EX)
        try:
            fcntl.flock(lock, fcntl.LOCK_EX if alone else fcntl.LOCK_SH)
        finally:
            if not alone:
                fcntl.flock(gate, fcntl.LOCK_UN)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
            fcntl.flock(gate, fcntl.LOCK_UN)


@pytest.hookimpl(wrapper=True, tryfirst=True)  # outermost: the wait is no part of a test's timeout
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None) -> Iterator[object]:
    """Tests marked ``alone`` bound wall-clock times that the suite's other tests, running beside
    them on the same cores, push over (a daemon out within 2 s of SIGTERM, a camera's frame
    interval): under pytest-xdist they run while no other test does."""
    if "PYTEST_XDIST_WORKER" not in os.environ:
        return (yield)
    # the locks beside the workers' temporary directories (pytest-xdist's basetemp/popen-gwN)
    with turn(Path(item.config.option.basetemp).parent, item.get_closest_marker("alone") is not None):
        return (yield)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_node_collection_finished(node, ids: list[str]) -> None:
    config = node.config
    if config.option.collectonly or config.stash.get(_WARMED, False):
        return
    config.stash[_WARMED] = True
    warm_daemon_kernels([nodeid.split("::")[0] for nodeid in ids])


_WARMED = pytest.StashKey[bool]()
