"""`edgedsm bench` and `edgedsm reproduce` run the lab (edgedsm_lab), which installs apart from the
product (lab/pyproject.toml): without it each says in one line how to install it and exits 69;
with it the suites are there (their own tests run them: tests/unit/bench, tests/unit/report)."""

from __future__ import annotations

import sys

import pytest

from edgedsm.cli import main
from edgedsm.commands.bench import SUITES
from edgedsm.commands.common import LAB_INSTALL


@pytest.fixture
def no_lab(monkeypatch: pytest.MonkeyPatch) -> None:
    """This interpreter as one without the lab: importing edgedsm_lab fails as it would there."""
    for name in [name for name in sys.modules if name == "edgedsm_lab" or name.startswith("edgedsm_lab.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "edgedsm_lab", None)  # None: ModuleNotFoundError(name="edgedsm_lab")


@pytest.mark.parametrize("argv", [["bench", "sim", "--quick"], ["bench"], ["bench", "e2e", "--frames", "9"],
                                  ["reproduce", "--quick", "-o", "unused"]])
def test_without_the_lab_a_lab_command_says_how_to_install_it(no_lab: None, argv: list[str],
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    assert main(argv) == 69
    out, err = capsys.readouterr()
    assert out == ""
    assert err.count("\n") == 1 and err.startswith(f"edgedsm: not installed: edgedsm {argv[0]} needs the lab")
    assert err.rstrip().endswith(LAB_INSTALL) and "pip install -e ./lab" in err


def test_with_the_lab_every_suite_is_a_choice(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exited:
        main(["bench", "--help"])
    assert exited.value.code == 0
    usage = capsys.readouterr().out
    assert "not installed" not in usage
    assert all(name in usage for name in SUITES)
