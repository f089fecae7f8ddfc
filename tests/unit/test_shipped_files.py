"""What the package ships (edgedsm/data/): every config valid as shipped, every scene loadable,
and ONE copy of each: the package's data/config and data/systemd are links to the repository's
config/ and systemd/, so the examples users read and the files an installed edgedsm uses cannot
drift apart."""

from __future__ import annotations

from pathlib import Path

import pytest

from edgedsm.cli import main
from edgedsm.commands.demo import DEMO_CONFIG
from edgedsm.resources import data_file
from edgedsm.sim import load_scene

REPO = Path(__file__).resolve().parents[2]
DAEMON_CONFIGS = sorted(data_file("config/daemon").glob("*.toml"))
SCENES = sorted(data_file("config/scenes").glob("*.toml"))


def test_package_data_is_the_repository_copy() -> None:
    assert data_file("config").resolve() == (REPO / "config").resolve()
    assert data_file("systemd").resolve() == (REPO / "systemd").resolve()
    assert data_file("config").is_symlink() and data_file("systemd").is_symlink()
    assert [p.name for p in DAEMON_CONFIGS] == ["demo.toml", "example.toml"]
    assert len(SCENES) >= 5
    assert data_file("systemd/edgedsm@.service").is_file()


@pytest.mark.parametrize("config", DAEMON_CONFIGS, ids=lambda p: p.name)
def test_every_shipped_config_passes_check_config(config: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["check-config", str(config)]) == 0
    assert capsys.readouterr().out.startswith(f"{config}: OK")


@pytest.mark.parametrize("scene", SCENES, ids=lambda p: p.name)
def test_every_shipped_scene_loads(scene: Path) -> None:
    loaded = load_scene(scene)
    assert loaded.scene.size > 0 and loaded.scene.frames > 0


def test_demo_reads_the_packaged_config() -> None:
    assert data_file("config/daemon/demo.toml") == DEMO_CONFIG
    assert DEMO_CONFIG.is_file()
