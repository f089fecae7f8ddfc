"""``analyze --json`` (a map over the whole frame) and ``analyze --timeline`` (the region 'frame'
covering it) are one measurement (edgedsm.measurement): on the same frames they report the same
noise floor, the same value above it and the same signal quality, on a real recording and on the
simulator; the pixels judged are named (``noise_view``), and the daemon's patch is another view."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from edgedsm.cli import main
from edgedsm.sim import Simulator, load_scene

REPO = Path(__file__).resolve().parents[3]
VIDEO = REPO / "tests" / "data" / "blueberry-biospeckle" / "A5LEP.mp4"
SCENE = (REPO / "config" / "scenes" / "drying_demo.toml").read_text().replace("size = 128", "size = 48")


def _map(frames: Path, estimator: str, tmp_path: Path, capsys, *extra: str) -> dict:
    assert main(["analyze", str(frames), "--estimator", estimator, "--window", "100", "--lag", "5",
                 "-o", str(tmp_path / f"{estimator}.npy"), "--json", "--no-progress", *extra]) == 0
    return json.loads(capsys.readouterr().out)


def _timeline(frames: Path, estimator: str, tmp_path: Path, capsys, *extra: str) -> dict:
    out = tmp_path / f"timeline-{estimator}"
    assert main(["analyze", str(frames), "--estimator", estimator, "--window", "100", "--lag", "5", "--timeline",
                 str(out), "--frames", "100", "--no-progress", *extra]) == 0
    capsys.readouterr()
    with (out / "timeline.csv").open(newline="") as handle:
        (row,) = list(csv.DictReader(handle))  # 100 frames: one sample, of the window analysed above
    return row


def _agree(mapped: dict, row: dict, estimator: str) -> None:
    assert row["region"] == "frame" and row["noise_view"] == mapped["noise_view"] == "region"
    # the CSV holds 6 significant digits
    assert float(row[estimator]) == pytest.approx(mapped["mean"], rel=2e-6)
    assert mapped["noise_floor"] is not None
    assert float(row["noise_floor"]) == pytest.approx(mapped["noise_floor"], rel=2e-6)
    assert float(row[f"{estimator}_above_noise"]) == pytest.approx(mapped["above_noise"], rel=2e-6, abs=1e-9)
    assert row["signal"] == mapped["signal"]["quality"]
    judged = mapped["activity"]
    assert (row["activity"] == "nan") if judged is None else float(row["activity"]) == pytest.approx(judged, rel=2e-6)


@pytest.mark.parametrize("estimator", ["s2", "s3"])
def test_the_map_and_the_timeline_agree_on_the_blueberry_video(estimator, tmp_path, capsys):
    mapped = _map(VIDEO, estimator, tmp_path, capsys, "--channel", "red")
    row = _timeline(VIDEO, estimator, tmp_path, capsys, "--channel", "red")
    _agree(mapped, row, estimator)
    # the whole frame is mostly the dark background: the frame is dark, its S2 mostly noise
    if estimator == "s2":
        assert mapped["signal"]["quality"] == "dark" and mapped["activity"] is None
        assert 0 < mapped["above_noise"] < 0.05 * mapped["mean"]
    # the daemon's view, a 64-px patch at the centre (the lit berry), is another view, and says so
    (tmp_path / "patch").mkdir()
    patch = _timeline(VIDEO, estimator, tmp_path / "patch", capsys, "--channel", "red", "--noise-patch", "64")
    patched = _map(VIDEO, estimator, tmp_path / "patch", capsys, "--channel", "red", "--noise-patch", "64")
    assert patch["noise_view"].startswith("patch 64x64") and patched["noise_view"] == patch["noise_view"]
    assert float(patch["noise_floor"]) == pytest.approx(patched["noise_floor"], rel=2e-6)
    assert patch["signal"] == patched["signal"]["quality"] != "dark"  # the patch is on the lit berry
    if estimator == "s2":  # S3's floor is 2/√π whatever the light
        assert patched["noise_floor"] < mapped["noise_floor"] / 2


def test_the_map_and_the_timeline_agree_on_the_simulator(tmp_path, capsys):
    scene = tmp_path / "scene.toml"
    scene.write_text(SCENE)
    frames = tmp_path / "frames.npy"
    np.save(frames, np.stack(list(Simulator(load_scene(scene)).frames(100))))
    for estimator in ("s1", "s2", "s3"):
        mapped = _map(frames, estimator, tmp_path, capsys, "--noise-gain", "0.25")
        row = _timeline(frames, estimator, tmp_path, capsys, "--noise-gain", "0.25")
        _agree(mapped, row, estimator)
        assert mapped["signal"]["quality"] == "ok" and mapped["activity"] == pytest.approx(mapped["above_noise"])
