"""The reproduction report's headline: the paper's findings tallied once per phase-noise reading."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from edgedsm_lab.report.findings import tally_by_reading
from edgedsm_lab.report.markdown import headline
from edgedsm_lab.report.plan import Settings
from edgedsm_lab.report.reproduce import reproduce

RESULTS = Path(__file__).resolve().parents[3] / "docs" / "reproduction" / "results.json"


def _stored() -> tuple[Settings, dict]:
    results = json.loads(RESULTS.read_text(encoding="utf-8"))
    fields = {k: tuple(v) if isinstance(v, list) else v for k, v in results["settings"].items()}
    return Settings(**fields), results


def test_each_reading_is_tallied_on_its_own_runs() -> None:
    settings, results = _stored()
    tallies = {t.reading: t for t in tally_by_reading(settings, results)}
    assert set(tallies) == {"white", "ou", "walk"}
    failed = {r: [n for n, f in enumerate(t.findings, start=1) if f.verdict == "not confirmed"]
              for r, t in tallies.items()}
    assert failed["white"] == [7]  # the logos stay visible at α = 0.5
    assert failed["walk"] == [2]  # S1 shifts far more than "slightly"
    assert all(len(t.findings) == 14 for t in tallies.values())
    assert tallies["walk"].borrowed == ["fig4"] and tallies["white"].borrowed == []
    text = headline(settings, results)
    assert "| white | 10 | 3 | 1 |" in text and "| walk | 10 | 3 | 1 |" in text


@pytest.mark.slow
def test_a_regenerated_report_keeps_the_headline(tmp_path: Path) -> None:
    report = reproduce(tmp_path, quick=True).read_text(encoding="utf-8")
    assert report.index("## Headline") < report.index("## Set-up")
    assert sum(f"| {reading} |" in report for reading in ("white", "ou", "walk")) == 3
