"""`edgedsm init NAME`: a config from the annotated template, validated, 0640, never overwritten."""

from __future__ import annotations

import os
import stat
import tomllib
from pathlib import Path

import numpy as np
import pytest

from edgedsm.cli import main
from edgedsm.resources import data_file

TEMPLATE = data_file("config/daemon/example.toml")


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_writes_a_valid_config_from_the_template(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    previous = os.umask(0)  # the mode must not depend on the caller's umask
    try:
        assert main(["init", "line5", "--dir", str(tmp_path / "etc")]) == 0
    finally:
        os.umask(previous)
    written = tmp_path / "etc" / "line5.toml"
    assert mode(written) == 0o640
    assert written.read_text() == TEMPLATE.read_text().replace("line3", "line5")
    data = tomllib.loads(written.read_text())
    assert (data["device"]["name"], data["mqtt"]["username"]) == ("line5", "edgedsm-line5")
    assert sorted(p.name for p in written.parent.iterdir()) == ["line5.toml"]  # no staging file left
    out = capsys.readouterr().out
    assert out.startswith(f"wrote {written} (mode 0640")
    assert "systemctl enable --now edgedsm@line5" in out
    assert f"edgedsm check-config {written}" in out
    assert main(["check-config", str(written)]) == 0


def test_camera_uri_is_filled_in(tmp_path: Path) -> None:
    recording = tmp_path / "rec" / 'line "a".npy'  # a quote must survive into the TOML string
    recording.parent.mkdir()
    np.save(recording, np.zeros((4, 8, 8), np.uint8))
    uri = f"replay:{recording}"
    assert main(["init", "cam2", "--dir", str(tmp_path), "--camera", uri]) == 0
    data = tomllib.loads((tmp_path / "cam2.toml").read_text())
    assert data["camera"]["uri"] == uri
    assert data["camera"]["exposure_us"] == 20000  # the rest of the table is the template's


def test_bad_camera_uri_writes_nothing(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["init", "cam3", "--dir", str(tmp_path), "--camera", "gige:1234"]) == 78
    assert "gige" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name", ["../evil", ".hidden", "", "a b", "x" * 65, "_under", "semi;colon"])
def test_bad_names_are_refused(name: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["init", name, "--dir", str(tmp_path)]) == 78
    assert "NAME" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_never_overwrites_without_force(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    existing = tmp_path / "line3.toml"
    existing.write_text("# hand-edited, keep me\n")
    assert main(["init", "line3", "--dir", str(tmp_path)]) == 78
    assert existing.read_text() == "# hand-edited, keep me\n"
    assert f"{existing} exists already" in capsys.readouterr().err
    assert main(["init", "line3", "--dir", str(tmp_path), "--force"]) == 0
    assert existing.read_text() == TEMPLATE.read_text()
    assert mode(existing) == 0o640
    assert sorted(p.name for p in tmp_path.iterdir()) == ["line3.toml"]
