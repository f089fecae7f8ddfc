"""`edgedsm bench accuracy`: its measures on known inputs, and the quick run's tables and numbers."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest
from scipy import special

from edgedsm.commands import bench
from edgedsm_lab.bench.accuracy import QUICK, cnr, edge_width, measure, smoothed
from edgedsm_lab.bench.accuracy_report import kept_from, write_report
from edgedsm_lab.bench.report import Report


def test_edge_width_of_a_gaussian_edge_is_2_56_sigma() -> None:
    x = np.arange(64, dtype=np.float64)
    for sigma in (1.5, 4.0):
        row = 2.0 + 3.0 * 0.5 * (1 + special.erf((x - 30.0) / (np.sqrt(2) * sigma)))
        noise = np.random.default_rng(0).normal(0, 0.05, (32, 64))
        assert edge_width(row + noise) == pytest.approx(2 * 1.2816 * sigma, rel=0.05)


def test_cnr_and_smoothing_on_known_maps() -> None:
    rng = np.random.default_rng(1)
    values = rng.normal(0.0, 1.0, (64, 64))
    values[:, :32] += 2.0
    left, right = np.zeros((64, 64), bool), np.zeros((64, 64), bool)
    left[:, :22], right[:, 42:] = True, True
    assert cnr(values, left, right) == pytest.approx(2.0, abs=0.15)
    assert smoothed(values, "box", 1) is values
    # a 5 x 5 box averages 25 independent values: the noise falls 5x, the CNR rises ~5x
    assert cnr(smoothed(values, "box", 5), left, right) == pytest.approx(10.0, rel=0.2)


def test_a_regeneration_keeps_the_light_section_and_its_row(tmp_path, repo) -> None:
    section, rows = kept_from(repo / "docs" / "accuracy.md")
    assert section[0].startswith("## 5. What if the light changes")
    assert "## How to choose" not in section and any("bench light" in line for line in section)
    assert len(rows) == 1 and rows[0].startswith("| light that changes during the run")
    assert kept_from(tmp_path / "absent.md") == ([], [])
    (tmp_path / "other.md").write_text("# x\n\n## How to choose\n\n| a | b | (table 5) |\n")
    assert kept_from(tmp_path / "other.md") == ([], [])


def test_bench_lists_the_accuracy_suite() -> None:
    parser = argparse.ArgumentParser()
    bench.add_arguments(parser)
    args = parser.parse_args(["accuracy", "--quick"])
    assert args.quick and args.output is None


# Both tests of the quick run on one pytest-xdist worker: the run (a module fixture) takes long
# enough to be measured once, not once per worker. (Slow unit tests share that worker anyway:
# tests/conftest.py.)
QUICK_RUN = pytest.mark.xdist_group("cpu_bound")
REPO = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def quick(tmp_path_factory: pytest.TempPathFactory):
    results = measure(QUICK)
    folder = tmp_path_factory.mktemp("accuracy")
    report = Report("Accuracy against time", echo=lambda _line: None)
    write_report(report, results, None, "edgedsm bench accuracy --quick", folder / "accuracy",
                 kept_from(REPO / "docs" / "accuracy.md"))
    path = report.save(folder / "accuracy.md")
    return results, path


@pytest.mark.slow
@QUICK_RUN
def test_quick_run_tables_and_figures(quick) -> None:
    results, path = quick
    text = path.read_text()
    assert len(results.contrast_n) == 2 * (4 + 4) * len(QUICK.windows)  # S1-S3, 1/τc and 4 descriptors
    assert len(results.contrast_m) == 2 * (3 + 2) * len(QUICK.lags)  # S1-S3, Fujii, IM (GD, contrast: no lag)
    assert len(results.cases) == 4 * 8
    # sliding: everything; tumbling: no GD; exponential: no τc, no GD
    assert len(results.delays) == (8 + 7 + 6) * len(QUICK.step_windows)
    assert len(results.smoothing) == 2 * len(QUICK.kernels)
    headings = ("## 1.", "### 1b.", "### 1c.", "## 2.", "## 3.", "## 4.", "## 5.", "## How to choose")
    assert [text.index(heading) for heading in headings] == sorted(text.index(heading) for heading in headings)
    assert text.index("| uneven laser light") < text.index("| light that changes during the run") \
        < text.index("| `fujii`")
    for label in ("| Fujii |", "| GD |", "| IM |", "| σ/⟨I⟩ |", "| `fujii`", "| `gd`", "| `im`", "| `contrast`"):
        assert label in text  # the cases table's rows and the how-to-choose rows
    for name in ("contrast-vs-window", "descriptors-vs-window", "contrast-vs-lag", "step-response", "smoothing"):
        figure = path.parent / "accuracy" / f"{name}.png"
        assert figure.stat().st_size > 10_000
        assert f"(accuracy/{name}.png)" in text
    assert all(0 < ms < float("inf") for ms in results.cost.values())
    for n in QUICK.windows:
        for name in ("fujii", "gd", "im", "contrast"):
            assert ("sliding", name, n) in results.cost
    assert not any(name == "gd" and mode != "sliding" for mode, name, _ in results.cost)  # GD: sliding only


@pytest.mark.slow
@QUICK_RUN
def test_quick_run_numbers(quick) -> None:
    results, _ = quick
    beta = {(noise, name, n): b for noise, name, n, b, _ in results.contrast_n}
    small, large = min(QUICK.windows), max(QUICK.windows)
    # S3's contrast grows with N (σ of a slow pixel is underestimated in a short window) ...
    assert beta["clean", "s3", large] > beta["clean", "s3", small] + 0.1
    # ... while S1's does not move much
    s1 = [beta["clean", "s1", n] for n in QUICK.windows]
    assert max(s1) - min(s1) < 0.08
    assert beta["clean", "s1", large] > beta["noisy", "s1", large] + 0.1  # noise costs contrast
    delays = {(mode, n, name): (d50, d90) for mode, n, name, d50, d90 in results.delays}
    for n in QUICK.step_windows:
        assert delays["tumbling", n, "s3"][0] == n  # the first whole block after the step
        assert delays["sliding", n, "s1"][0] < n  # half the window is enough for half the way
    levels = {(mode, n, name): after for mode, n, name, _, after in results.levels}
    s3 = [levels["sliding", n, "s3"] for n in QUICK.step_windows]
    assert s3[0] > s3[1] > s3[2]  # S3's level after the step is not portable across N
    s1_levels = [levels["sliding", n, "s1"] for n in QUICK.step_windows]
    assert max(s1_levels) / min(s1_levels) < 1.1
    widths = {(kind, k): w for kind, k, _, _, w, _ in results.smoothing}
    assert widths["box", 9] > widths["box", 1] + 3  # smoothing costs resolution


@pytest.mark.slow
@QUICK_RUN
def test_quick_run_descriptor_numbers(quick) -> None:
    results, _ = quick
    small, large = min(QUICK.windows), max(QUICK.windows)
    pair = {(noise, name, n): (b, a) for noise, name, n, b, a in results.contrast_n}
    lagged = {(noise, name, m): (b, a) for noise, name, m, b, a in results.contrast_m}
    assert all(np.isfinite(b) and np.isfinite(a) for b, a in [*pair.values(), *lagged.values()])
    # Fujii is 200·S2 (its eps against S2's q = 0 moves no rank): S2's β and AUC, at every N and m
    for keyed in (pair, lagged):
        for (noise, name, x), (beta, area) in keyed.items():
            if name == "fujii":
                assert beta == pytest.approx(keyed[noise, "s2", x][0], abs=1e-9)
                assert area == pytest.approx(keyed[noise, "s2", x][1], abs=1e-6)
    # IM ranks the logos above the background, better with N, worse with phase noise
    assert pair["clean", "im", large][1] > 0.8
    assert pair["clean", "im", large][1] > pair["clean", "im", small][1] + 0.1
    assert pair["clean", "im", large][0] > pair["noisy", "im", large][0] + 0.1
    # GD compares every pair of the window: once N >> τc both levels decorrelate inside it and
    # GD reads the intensity spread, so its AUC falls with N while S2's rises
    assert pair["clean", "gd", large][1] < pair["clean", "gd", small][1] - 0.03
    assert pair["clean", "gd", large][1] < pair["clean", "s2", large][1] - 0.15
    assert 0.5 < pair["clean", "gd", small][1] < 0.75
    # temporal contrast: finite, and its finite-window bias makes its settled level after the
    # step grow with N (not portable), below the level before the step (slower = lower σ/⟨I⟩)
    levels = {(mode, n, name): (before, after) for mode, n, name, before, after in results.levels}
    contrast = [levels["sliding", n, "contrast"] for n in QUICK.step_windows]
    assert contrast[0][1] < contrast[1][1] < contrast[2][1]
    assert all(after < before - 0.05 for before, after in contrast)
    # the engine's Fujii is 200 × its S2 in every mode (q = 0)
    for mode, n, name in levels:
        if name == "fujii":
            assert levels[mode, n, name][1] == pytest.approx(200 * levels[mode, n, "s2"][1], rel=1e-9)
    delays = {(mode, n, name): d50 for mode, n, name, d50, _ in results.delays}
    for n in QUICK.step_windows:
        for name in ("fujii", "im", "contrast"):
            assert delays["tumbling", n, name] == n  # the first whole block after the step
        assert delays["sliding", n, "gd"] < n
        assert ("tumbling", n, "gd") not in delays
    cases = {(case, name): (b, a) for case, name, b, a in results.cases}
    for name in ("s1", "im", "gd"):  # phase noise costs every difference-based map contrast
        assert cases["phase noise", name][0] < cases["clean", name][0] - 0.05
