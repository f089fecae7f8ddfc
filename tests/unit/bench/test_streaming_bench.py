"""`edgedsm bench engine` runs end to end on tiny sizes and writes its report."""

from __future__ import annotations

import importlib.util

import pytest

from edgedsm.cli import main


@pytest.mark.slow
def test_bench_engine_writes_tables_and_plot(tmp_path, capsys):
    report = tmp_path / "bench-engine.md"
    code = main(["bench", "engine", "--quick", "--sizes", "64", "--window", "20", "--lag", "3",
                 "--numpy-frames", "3", "--noise-frames", "60", "-o", str(report)])
    assert code == 0
    text = report.read_text()
    assert "| 64x64 | sliding |" in text and "| 64x64 | exponential |" in text
    # sliding and tumbling reproduce the batch S1 and S3 exactly
    for line in text.splitlines():
        if line.startswith(("| 64x64 | sliding | numba |", "| 64x64 | tumbling | numba |")) \
                and "1 thread" not in line:
            assert "| 0 / " in line and line.split("|")[-3].strip().endswith("/ 0")
    if importlib.util.find_spec("numba"):
        assert "state bit-identical to numba: yes" in text
        assert "bit-identical to numba: NO" not in text
    assert "## Map noise at constant activity" in text and "| 25 |" in text
    assert "## Correlation time τc" in text and "| 64x64 | tau_c (K = 6) |" in text
    assert "| 64x64 | s1+s2+s3+tau_c (K = 6) |" in text
    assert "## The field's streaming descriptors" in text
    assert "## Each map alone" in text
    alone = {name: [cell.strip() for cell in next(line for line in text.splitlines()
                                                    if line.startswith(f"| 64x64 | {name} |")).split("|")]
             for name in ("s1", "s2", "s3")}
    assert alone["s1"][5] == "1.00"  # x S1 of S1 itself
    deep = {(cells[2], cells[3]): cells for cells in ([cell.strip() for cell in line.split("|")]
                                                      for line in text.splitlines() if line.startswith("| 64x64 | 1"))}
    assert deep[("12", "s2")][4] == deep[("16", "s1+s2+s3")][4] == "float"  # S2's term kind
    assert deep[("12", "s1")][6] == deep[("16", "s1")][6] == "1.00" and len(deep) == 8
    assert float(alone["s2"][7]) > float(alone["s1"][7])  # S2 moves its fixed-point sum too
    moved = {}
    for name in ("s1+s2+s3", "s1+s2+s3+contrast", "s1+s2+s3+fujii", "s1+s2+s3+im", "s1+s2+s3+gd",
                 "s1+s2+s3+band_ratio"):
        line = next(line for line in text.splitlines() if line.startswith(f"| 64x64 | {name} "))  # S1-S3: (K = 6)
        cells = [cell.strip() for cell in line.split("|")]
        moved[name] = float(cells[7])
        assert float(cells[8]) > 0  # x its own bandwidth bound
    # contrast and Fujii reuse S3's and S2's sums; GD reads the N = 20 ring frames (1 B each at
    # 8 bits) and reads and writes its int64 sum (2 x 8 B)
    assert moved["s1+s2+s3+contrast"] == moved["s1+s2+s3+fujii"] == moved["s1+s2+s3"]
    assert moved["s1+s2+s3+gd"] == moved["s1+s2+s3"] + 20 + 16
    assert moved["s1+s2+s3+im"] > moved["s1+s2+s3"]
    # the band ratio at N = 20, split 0.25 cycles per frame: the 5 low bins (16 B each) read and
    # written, and the re-anchor's N frames of 1/N of the pixels (1 B per pixel)
    assert moved["s1+s2+s3+band_ratio"] == moved["s1+s2+s3"] + 2 * 16 * 5 + 1
    if importlib.util.find_spec("matplotlib"):
        assert (tmp_path / "bench-engine.png").stat().st_size > 10_000
    assert "Measured memory bandwidth" in capsys.readouterr().out
