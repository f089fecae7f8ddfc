"""`edgedsm bench dashboard` (the lab's, once edgedsm/dashboard/loadbench.py): a private mosquitto,
the dashboard as its own process with a page attached, and a load generator; the table it writes
counts what the generator sent and what reached the page."""

from __future__ import annotations

from pathlib import Path

import pytest

from edgedsm.cli import main

pytestmark = [pytest.mark.integration, pytest.mark.slow]


def test_bench_dashboard_measures_the_load_it_sends(tmp_path: Path) -> None:
    out = tmp_path / "dashboard.md"
    code = main(["bench", "dashboard", "--devices", "2", "--seconds", "3", "--warmup", "1.5", "--tmp", str(tmp_path),
                 "-o", str(out)])
    assert code == 0
    (row,) = [line for line in out.read_text(encoding="utf-8").splitlines() if line.startswith("| 2 |")]
    _, rate, messages, kib, cpu, events = (cell.strip() for cell in row.strip("|").split("|"))
    # two devices at one update a second: a statistics message each (the states, alerts and maps come at
    # phases 0, 10, 20 ... of each device's minute, outside the 1.5-4.5 s measured here)
    assert rate == "1.0" and 1.3 <= float(messages) <= 3.4
    assert 0.5 * float(messages) <= float(kib) <= 4.0 * float(messages)  # a statistics message: ~1 KiB
    assert 0.0 <= float(cpu.rstrip(" %")) < 100.0
    assert 0.5 <= float(events) <= float(messages) + 1.0  # the page receives what the dashboard got
