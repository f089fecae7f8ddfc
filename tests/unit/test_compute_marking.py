"""Which tests the suite runs at idle priority beside the ``alone`` ones (tests/conftest.py): those
that only compute."""

from __future__ import annotations

from types import SimpleNamespace

from tests.conftest import REPO, computes_only


def marked(path: str, *marks: str) -> SimpleNamespace:
    return SimpleNamespace(path=REPO / path, get_closest_marker=lambda name: name if name in marks else None)


def test_the_tests_that_only_compute() -> None:
    assert computes_only(marked("tests/unit/estimators/test_region_stats.py"))
    assert computes_only(marked("tests/unit/commands/test_analyze_inputs.py", "slow"))  # a slow unit test
    assert not computes_only(marked("tests/unit/commands/test_cli.py"))  # may bound a wall-clock time
    assert not computes_only(marked("tests/integration/test_wheel.py", "slow"))  # waits on programs
    assert not computes_only(marked("tests/unit/estimators/test_x.py", "alone"))
