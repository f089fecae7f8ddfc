"""The benchmark report helper every `edgedsm bench` suite writes its markdown with."""

from __future__ import annotations

import os
import platform

import pytest

from edgedsm.bench.report import Report, machine_header, markdown_table


def test_markdown_table_aligns_and_escapes() -> None:
    lines = markdown_table(["case", "max |ΔS|", "fps"], [["a", 1.5, "12"], ["b|c", 2, "3"]], align="lrr")
    assert lines == ["| case | max \\|ΔS\\| | fps |", "|---|---:|---:|",
                     "| a | 1.5 | 12 |", "| b\\|c | 2 | 3 |"]
    assert markdown_table(["x", "y", "z"], [])[1] == "|---|---:|---:|"  # default: first column left


def test_markdown_table_refuses_mismatched_rows_and_alignment() -> None:
    with pytest.raises(ValueError, match="2 cells for 3 columns"):
        markdown_table(["a", "b", "c"], [["1", "2"]])
    with pytest.raises(ValueError, match="one 'l' or 'r' per column"):
        markdown_table(["a", "b"], [], align="lc")


def test_machine_header_names_command_machine_versions_and_load() -> None:
    text = machine_header("edgedsm bench foo --quick", "numba", load=0.5, load_after=1.25)
    assert text.startswith("`edgedsm bench foo --quick` on ")
    assert f"({platform.machine()}), {os.cpu_count()} logical CPUs" in text
    assert f"Python {platform.python_version()}" in text and "numba" in text
    assert text.endswith("; load average 0.50 before the run, 1.25 after it.")
    assert "load average" not in machine_header("edgedsm bench foo")


def test_report_prints_each_line_and_saves_the_same(tmp_path) -> None:
    printed: list[str] = []
    report = Report("Foo benchmark", echo=printed.append)
    report.line("set-up")
    report.table(["a", "b"], [[1, 2]])
    path = report.save(tmp_path / "docs" / "bench-foo.md")
    assert printed == ["# Foo benchmark", "", "set-up", "| a | b |", "|---|---:|", "| 1 | 2 |"]
    assert path.read_text(encoding="utf-8") == "\n".join(printed) + "\n"
