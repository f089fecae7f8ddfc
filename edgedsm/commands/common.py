"""Pieces shared by several commands."""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Iterable, Iterator
from types import ModuleType
from typing import TYPE_CHECKING, TypeVar

from edgedsm.errors import EdgedsmError

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


#: The lab's one-line install hint (its project is lab/ in the repository; ./scripts/test.sh installs it).
LAB_INSTALL = "pip install -e ./lab in the edgedsm repository (./scripts/test.sh installs it)"


class LabNotInstalled(EdgedsmError):
    """The lab (edgedsm_lab: the benchmarks and the paper's reproduction) ships apart from the
    product and is not installed. Exit code 69 (EX_UNAVAILABLE: a support program is missing)."""

    exit_code = 69
    kind = "not installed"


def lab_installed() -> bool:
    try:
        importlib.import_module("edgedsm_lab")
    except ModuleNotFoundError as exc:
        if exc.name == "edgedsm_lab":
            return False
        raise
    return True


def lab_module(name: str, what: str) -> ModuleType:
    """The lab's module ``name``, loaded by name: edgedsm never imports the lab, which installs
    apart (docs/architecture.md, "Layers"); ``what`` names the command that needs it."""
    if not lab_installed():
        raise LabNotInstalled(f"{what} needs the lab (edgedsm_lab): {LAB_INSTALL}")
    return importlib.import_module(name)
