"""Fixtures the dashboard's tests share."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from edgedsm.dashboard.history import History


@pytest.fixture
def history(tmp_path: Path) -> Iterator[History]:
    """A day-long history in the test's folder, closed afterwards."""
    store = History(tmp_path / "history.sqlite3", retention_s=86400.0)
    yield store
    store.close()
