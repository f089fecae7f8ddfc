"""The README's Python API example runs as written, from any directory (not only the repository's)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import REPO


def api_example() -> str:
    readme = (REPO / "README.md").read_text()
    section = readme.split("## Python API", 1)[1]
    found = re.search(r"```python\n(.*?)```", section, re.S)
    assert found, "README.md: no python block under '## Python API'"
    return found.group(1)


@pytest.mark.timeout(120)
def test_the_readme_python_example_runs_outside_the_repository(tmp_path: Path) -> None:
    code = api_example() + "\nprint(sorted(maps), float(abs(maps['s3'] - activity).max()))\n"
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=110)
    assert done.returncode == 0, done.stderr
    names, difference = done.stdout.strip().rsplit(" ", 1)
    assert names == "['s1', 's2', 's3']"
    assert float(difference) <= 1e-12  # the engine's S3 is the batch reference's (docs/engine.md)
