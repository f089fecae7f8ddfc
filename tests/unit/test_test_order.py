"""How the suite hands its tests out (tests/conftest.py): the tests that only compute are marked
for the idle-priority run beside the ``alone`` tests, and the waiting kinds' modules are spread
among the computing ones, each module whole."""

from __future__ import annotations

import itertools
from pathlib import Path
from types import SimpleNamespace

from tests.conftest import REPO, computes_only, interleave_modules


def fake_items(counts: dict[str, int]) -> list[SimpleNamespace]:
    return [SimpleNamespace(path=REPO / module, index=i) for module, count in counts.items() for i in range(count)]


def test_waiting_modules_are_spread_among_the_others_each_module_whole() -> None:
    counts = {"tests/faults/test_a.py": 6, "tests/faults/test_b.py": 4, "tests/integration/test_c.py": 10,
              "tests/unit/test_d.py": 12, "tests/unit/x/test_e.py": 8, "tests/unit/test_f.py": 20}
    items = fake_items(counts)
    merged = interleave_modules(items)
    assert sorted(map(id, merged)) == sorted(map(id, items))  # every test once
    runs = [path for path, _ in itertools.groupby(item.path for item in merged)]
    assert len(runs) == len(counts)  # each module's tests together ...
    for path in counts:  # ... in their own order
        assert [item.index for item in merged if item.path == REPO / path] == list(range(counts[path]))
    kinds = ["waiting" if {"faults", "integration"} & set(Path(path).parts) else "unit" for path in runs]
    assert kinds == ["unit", "waiting", "unit", "waiting", "unit", "waiting"], runs  # alternate by share


def test_one_kind_alone_keeps_the_collection_order() -> None:
    items = fake_items({"tests/unit/test_a.py": 3, "tests/unit/test_b.py": 2})
    assert interleave_modules(items) == items


def marked(path: str, *marks: str) -> SimpleNamespace:
    return SimpleNamespace(path=REPO / path, get_closest_marker=lambda name: name if name in marks else None)


def test_the_tests_that_only_compute() -> None:
    assert computes_only(marked("tests/unit/estimators/test_region_stats.py"))
    assert computes_only(marked("tests/unit/commands/test_analyze_inputs.py", "slow"))  # a slow unit test
    assert not computes_only(marked("tests/unit/commands/test_cli.py"))  # may bound a wall-clock time
    assert not computes_only(marked("tests/integration/test_wheel.py", "slow"))  # waits on programs
    assert not computes_only(marked("tests/unit/estimators/test_x.py", "alone"))
