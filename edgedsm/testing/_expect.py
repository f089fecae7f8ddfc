"""A pytest-free ``raises``: the contract checks run under any test runner (or none)."""

from __future__ import annotations

import contextlib
import re
import time
from collections.abc import Callable, Iterator


@contextlib.contextmanager
def expect_error(kind: type[BaseException], match: str | None = None, what: str = "") -> Iterator[None]:
    """Fail (AssertionError) unless the block raises ``kind`` whose message matches ``match``."""
    try:
        yield
    except kind as exc:
        if match is not None and not re.search(match, str(exc)):
            raise AssertionError(f"{what}: raised {type(exc).__name__}({exc}), but the message "
                                 f"does not match {match!r}") from exc
        return
    raise AssertionError(f"{what}: expected {kind.__name__}, nothing was raised")


def check(condition: bool, message: str) -> None:
    """``assert`` that survives ``python -O``: the contract must not vanish with optimisation."""
    if not condition:
        raise AssertionError(message)


def eventually(probe: Callable[[], bool], timeout_s: float) -> bool:
    """Whether ``probe()`` becomes true within ``timeout_s`` (polled every 5 ms)."""
    deadline = time.monotonic() + timeout_s
    while not probe():
        if time.monotonic() >= deadline:
            return probe()
        time.sleep(0.005)
    return True
