"""docs/descriptors.md agrees with the registry: its generated table is ``markdown_table()``, and
the hand-written table gives each map the registry's unit and says whether it has a noise floor;
the names of the field's descriptors are literals of at most 3 modules of edgedsm, the registry
among them."""

from __future__ import annotations

import ast
import re
from pathlib import Path

from edgedsm.estimators import registry

ROOT = Path(__file__).resolve().parents[3]
DOC = ROOT / "docs" / "descriptors.md"
BEGIN, END = "<!-- registry table: edgedsm.estimators.registry.markdown_table() -->\n", "<!-- end registry table -->"


def test_the_generated_table_is_the_registry() -> None:
    text = DOC.read_text(encoding="utf-8")
    assert text.count(BEGIN) == 1 and text.count(END) == 1
    assert text.split(BEGIN)[1].split(END)[0] == registry.markdown_table()


def _cells(line: str) -> list[str]:
    return [cell.strip() for cell in re.split(r"(?<!\\)\|", line.strip())[1:-1]]


def test_the_hand_table_gives_the_registrys_unit_and_floor() -> None:
    lines = DOC.read_text(encoding="utf-8").splitlines()
    header = lines.index(next(line for line in lines if line.startswith("| name | definition | BSLTL function")))
    columns = _cells(lines[header])
    seen = set()
    for line in lines[header + 2:]:
        if not line.startswith("|"):
            break
        row = dict(zip(columns, _cells(line), strict=True))
        for name in re.findall(r"`([a-z0-9_]+)`", row["name"]):
            record = registry.REGISTRY.get(name)
            if record is None:
                continue
            seen.add(name)
            assert row["unit"] == record.unit, name
            assert row["noise floor"].startswith("yes") == record.has_floor, name
    assert seen == {name for name, record in registry.REGISTRY.items() if record.batch is not None}


#: The modules whose literals are counted: all of edgedsm (issue 35: a map's name is the registry's;
#: elsewhere a property of its record says what the code needs, e.g. ``needs_q_zero``, ``cost``).
SOURCES = tuple(sorted((ROOT / "edgedsm").rglob("*.py")))


def test_descriptor_names_are_literals_of_at_most_three_modules() -> None:
    for name in ("contrast", "fujii", "im", "gd"):
        holders = [path.relative_to(ROOT).as_posix() for path in SOURCES
                   if any(isinstance(node, ast.Constant) and node.value == name
                          for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))))]
        assert "edgedsm/estimators/registry.py" in holders and len(holders) <= 3, (name, holders)
