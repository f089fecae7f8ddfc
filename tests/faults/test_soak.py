"""The short soak CI runs: `edgedsm bench soak --minutes 0.5` as a process (every fault kind at
least once), its markdown table read back: no alert lost, every laser-off delay within its bound,
the daemon stopped cleanly at the end.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
from helpers_mqtt import child_env

from edgedsm_lab.bench.soak import BOUNDS_S, FAULTS

pytestmark = [pytest.mark.faults, pytest.mark.integration, pytest.mark.slow]


def _table(lines: list[str], first_header: str) -> list[list[str]]:
    """The rows of the markdown table whose header starts with ``first_header``."""
    start = next(i for i, line in enumerate(lines) if line.startswith(f"| {first_header}"))
    rows = []
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        rows.append([cell.strip() for cell in line.strip("|").split("|")])
    return rows


@pytest.mark.timeout(120)
def test_short_soak_loses_no_alert_and_keeps_laser_off_delays_within_bounds(tmp_path: Path) -> None:
    output = tmp_path / "bench-soak.md"
    result = subprocess.run([sys.executable, "-m", "edgedsm", "bench", "soak", "--minutes", "0.5", "-o", str(output)],
                            capture_output=True, text=True, timeout=110, env=child_env())
    assert result.returncode == 0, result.stdout + result.stderr
    lines = output.read_text().splitlines()
    faults = {row[0]: row for row in _table(lines, "fault")}
    assert set(faults) == set(FAULTS)
    for kind, (_, injected, worst, bound) in faults.items():
        assert int(injected) >= 1, kind
        if kind in BOUNDS_S:
            assert worst != "-" and 0.0 < float(worst) <= float(bound) == pytest.approx(BOUNDS_S[kind], abs=0.05), \
                faults[kind]
    [summary] = _table(lines, "alerts (distinct)")
    alerts, copies, lost, _, _, _, code = summary
    assert int(lost) == 0
    assert int(alerts) >= len(FAULTS) and int(copies) >= int(alerts)
    assert code == "0"
    print("\n".join(lines))
