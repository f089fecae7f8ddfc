from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def repo() -> Path:
    return REPO

import sys  # noqa: E402 - the shared contract modules live beside this file

sys.path.insert(0, str(Path(__file__).resolve().parent))
