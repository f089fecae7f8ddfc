"""docs/python.md's worked example on the shipped real video runs and prints what the page says."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import REPO


@pytest.mark.timeout(180)
def test_the_python_page_example_runs_and_prints_what_the_page_says(tmp_path: Path) -> None:
    page = (REPO / "docs" / "python.md").read_text()
    code, printed = re.findall(r"```(?:python)?\n(.*?)```", page, re.S)[:2]
    code = code.replace('"s2.png"', repr(str(tmp_path / "s2.png")))  # the picture outside the repository
    done = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=170)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines()[:4] == printed.splitlines()[:4]  # reader, S2, Fujii, τc: decoded exactly
    error = float(done.stdout.splitlines()[4].rsplit(" ", 1)[1])
    assert error <= 1e-14  # the engine's S2 is the batch map's within its stated bound (docs/engine.md)
    assert (tmp_path / "s2.png").stat().st_size > 10_000
