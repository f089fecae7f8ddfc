"""`edgedsm analyze --estimator NAME` for the field's descriptors (docs/descriptors.md): the map is
the batch function's, the noise floor is the registry's (null with a reason where it has none), and the options
each one needs."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from edgedsm.cli import main
from edgedsm.estimators.bands import split_powers
from edgedsm.estimators.descriptors import DESCRIPTORS, fujii, gd, mhi


def _frames(tmp_path: Path) -> Path:
    path = tmp_path / "frames.npy"
    np.save(path, np.random.default_rng(4).integers(0, 256, (20, 12, 10)).astype(np.uint8))
    return path


def _json(capsys: pytest.CaptureFixture[str]) -> dict:
    return json.loads(capsys.readouterr().out)


def test_every_registry_name_is_an_estimator_choice(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _frames(tmp_path)
    for name in DESCRIPTORS:
        out = tmp_path / f"{name}.npy"
        assert main(["analyze", str(path), "--estimator", name, "--window", "16", "--lag", "2", "--threshold", "30",
                     "-o", str(out), "--json", "--no-progress"]) == 0, name
        result = _json(capsys)
        assert result["estimator"] == name and result["unit"] == DESCRIPTORS[name].unit
        assert np.isfinite(np.load(out)).all()
        assert result["lag"] == (2 if DESCRIPTORS[name].uses_lag else None) and result["dt"] is None
        if name in ("s1", "s2", "s3", "fujii", "im", "gd", "contrast"):  # the contrast: the daemon's floor too
            assert "noise_floor_reason" not in result and result["signal"] is not None
        else:
            assert result["noise_floor"] is None and name in result["noise_floor_reason"]


def test_the_map_is_the_batch_descriptor(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _frames(tmp_path)
    frames = np.load(path)[3:18]
    for name, args, expected in (("gd", [], gd(frames)), ("fujii", ["--lag", "3"], fujii(frames, 3)),
                                 ("mhi", ["--threshold", "40"], mhi(frames, 40)),
                                 ("band_high", ["--dt", "0.02", "--split", "10"],
                                  split_powers(frames, 0.02, 10.0)[1])):
        out = tmp_path / f"{name}.npy"
        assert main(["analyze", str(path), "--estimator", name, "--start", "3", "--window", "15", *args,
                     "-o", str(out), "--png", "--no-progress"]) == 0
        np.testing.assert_array_equal(np.load(out), expected)
        assert out.with_suffix(".png").stat().st_size > 0
        text = capsys.readouterr().out
        assert f"mean {expected.mean():.4g}" in text
        assert (f"no noise floor is known for {name} yet" in text) == (name not in ("gd", "fujii"))
        assert ("above noise: " in text) and ("(floor " in text or "unknown (" in text)
        assert (", lag 3:" in text) == (name == "fujii")
        assert (", frequencies in Hz (dt 0.02 s):" in text) == (name == "band_high")


def test_missing_or_bad_options_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _frames(tmp_path)
    out = str(tmp_path / "m.npy")
    assert main(["analyze", str(path), "--estimator", "mhi", "-o", out]) == 1
    assert capsys.readouterr().err.strip() == "edgedsm: error: mhi needs --threshold"
    assert main(["analyze", str(path), "--estimator", "band_ratio", "--dt", "0.1", "--split", "7", "-o", out]) == 1
    assert "Nyquist frequency 5" in capsys.readouterr().err
    assert main(["analyze", str(path), "--estimator", "skewness", "--timeline", str(tmp_path / "t")]) == 1
    assert "skewness is a batch map only" in capsys.readouterr().err


def test_gd_streams_with_timeline(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path, out = _frames(tmp_path), tmp_path / "t"
    assert main(["analyze", str(path), "--estimator", "gd", "--timeline", str(out), "--window", "10", "--every", "5",
                 "--no-tau-c", "--no-noise-floor", "--no-progress"]) == 0
    with (out / "timeline.csv").open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    frames = np.load(path)
    assert [int(row["frame"]) for row in rows] == [9, 14, 19] and list(rows[0])[-1] == "gd"
    for row in rows:  # the whole frame is one region; the CSV keeps 6 digits
        end = int(row["frame"]) + 1
        assert float(row["gd"]) == pytest.approx(gd(frames[end - 10:end]).mean(), rel=1e-5)
