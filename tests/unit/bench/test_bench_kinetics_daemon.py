"""The kinetics' daemon cost benchmark on a small frame: it runs, its memory is the kept
pixels' (slots + 1) × 4 bytes, subsampling keeps a step² share of the pixels, the table prints."""

from __future__ import annotations

from edgedsm_lab.bench.kinetics_daemon import main, measure, table


def test_the_benchmark_measures_each_step(capsys) -> None:
    rows = measure(64, [1, 4], rounds=3)
    full, sub = rows
    assert full["pixels"] == 64 * 64 and sub["pixels"] == 16 * 16
    assert full["memory"] == (full["slots"] + 1) * 4 * full["pixels"]
    assert sub["memory"] == (sub["slots"] + 1) * 4 * sub["pixels"]
    assert all(row["push_best"] > 0 and row["read_best"] > 0 and row["share_best"] > 0 for row in rows)
    text = table(rows)
    assert text.count("\n") == 4 and "| 4 | 256 |" in text
    assert main(["--size", "64", "--steps", "4", "--rounds", "3"]) == 0
    assert "default S1+S2+S3 push of 64²" in capsys.readouterr().out
