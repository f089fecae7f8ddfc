"""Pieces shared by several commands."""

from __future__ import annotations

import argparse
from collections.abc import Iterable, Iterator
from typing import TYPE_CHECKING, TypeVar

if TYPE_CHECKING:
    from edgedsm.sim import Scene

T = TypeVar("T")


def scene_argument(value: str) -> Scene:
    """A scene file path, or 'default' for the built-in logo scene."""
    from edgedsm.sim import load_scene

    return load_scene(value)


def progress(items: Iterable[T], total: int | None, description: str, enabled: bool = True) -> Iterator[T]:
    """A progress bar on stderr for long runs (hidden when stderr is not a terminal)."""
    from tqdm import tqdm

    yield from tqdm(items, total=total, desc=description, unit="frame", disable=None if enabled else True,
                    leave=False)


def add_progress_flag(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--no-progress", dest="progress", action="store_false",
                        help="do not show a progress bar")
