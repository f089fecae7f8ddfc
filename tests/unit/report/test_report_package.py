"""The report package's own pieces: the logo scene it ships, and its plan."""

from __future__ import annotations

import tomllib
from pathlib import Path

from edgedsm_lab.report.plan import Settings, logo_regions, plan_runs

REPO = Path(__file__).resolve().parents[3]


def test_logo_geometry_comes_from_package_data_not_the_repository(monkeypatch, tmp_path) -> None:
    monkeypatch.chdir(tmp_path)  # no config/ here: only the package's data can supply it
    regions, source = logo_regions(Settings.make(size=128, quick=True))
    assert source == "edgedsm/data/config/scenes/logos.toml"
    assert [r["text"] for r in regions] == ["IOMT", "ETRI"]
    assert regions[0]["x"] == 48 * 96 / 256  # quick caps size at 96 px; coordinates scale with it
    assert all(r["tau_c"] == 10.0 for r in regions)


def test_packaged_logo_scene_is_the_example_in_config() -> None:
    packaged = tomllib.loads((REPO / "edgedsm/data/config/scenes/logos.toml").read_text(encoding="utf-8"))
    example = tomllib.loads((REPO / "config/scenes/logos.toml").read_text(encoding="utf-8"))
    assert packaged == example and packaged["activity"]["regions"]


def test_quick_plan_size() -> None:
    plan = plan_runs(Settings.make(quick=True))
    assert len(plan) == 28  # optical simulations of `edgedsm reproduce --quick`
    assert sum(len(etas) for etas in plan.values()) == 46
