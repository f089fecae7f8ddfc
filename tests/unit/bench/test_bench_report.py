"""The benchmark report helper every `edgedsm bench` suite writes its markdown with."""

from __future__ import annotations

import os
import platform

import pytest

from edgedsm_lab.bench.report import Report, machine_header, markdown_table


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


def test_others_share_is_the_machine_busy_time_not_this_process() -> None:
    from edgedsm_lab.bench.report import CpuSample, others_share

    cpus = os.cpu_count() or 1
    before = CpuSample(busy_s=100.0, own_s=10.0, wall_s=50.0)
    # 2 s wall on every CPU: 1 s busy of our own, 0.5 s more from others
    after = CpuSample(busy_s=101.5, own_s=11.0, wall_s=52.0)
    assert others_share(before, after) == pytest.approx(0.5 / (2.0 * cpus))
    assert others_share(before, CpuSample(100.5, 11.0, 52.0)) == 0.0  # tick rounding: never below 0
    assert others_share(None, after) is None and others_share(before, before) is None


@pytest.mark.skipif(not os.path.exists("/proc/stat"), reason="/proc/stat is Linux's")
def test_a_busy_process_counts_as_other_work_until_it_is_ours() -> None:
    import subprocess
    import sys

    from edgedsm_lab.bench.report import cpu_sample, others_share

    before = cpu_sample()
    busy = ("import time\nend = time.process_time() + 0.6\nwhile time.process_time() < end: pass\n"
            "print('spent', flush=True)\ntime.sleep(60)")
    child = subprocess.Popen([sys.executable, "-c", busy], stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout is not None and child.stdout.readline() == "spent\n"
        running = cpu_sample()  # its 0.6 s of CPU spent, now asleep and not waited for yet
    finally:
        child.kill()
        child.communicate()
    reaped = cpu_sample()
    assert before is not None and running is not None and reaped is not None
    child_cpu = reaped.own_s - running.own_s  # its CPU time joins ours once waited for
    assert child_cpu >= 0.55
    expected = child_cpu / ((running.wall_s - before.wall_s) * (os.cpu_count() or 1))
    assert others_share(before, running) >= 0.8 * expected
    # the same time as ours: only what else ran (nothing much, here) is left
    assert others_share(before, reaped) <= others_share(before, running) - 0.7 * expected
