"""A real recording made by another project (tests/data/blueberry-biospeckle/README.md: a
blueberry's biospeckle filmed by a phone, H.264 MP4, Apache-2.0): the reading layer takes it as a
user would, and the estimators see real activity in it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from edgedsm.cli import main
from edgedsm.errors import DataError
from edgedsm.estimators import s1
from edgedsm.estimators.correlation_time import tau_c
from edgedsm.frameio import open_frames

VIDEO = Path(__file__).resolve().parents[2] / "data" / "blueberry-biospeckle" / "A5LEP.mp4"


def _fruit(frames: np.ndarray) -> np.ndarray:
    """The central 256x256 crop: the lit fruit (the background around it is dark)."""
    rows, cols = frames.shape[1] // 2, frames.shape[2] // 2
    return frames[:, rows - 128:rows + 128, cols - 128:cols + 128]


def test_the_phone_video_is_read_as_it_was_recorded() -> None:
    with open_frames(VIDEO, channel="red") as reader:
        assert (reader.count, reader.shape, reader.dtype, reader.bits) == (348, (614, 1092), np.uint8, 8)
        assert reader.dt == pytest.approx(1 / 30)
        assert reader.lossy and any("'h264' is lossy" in note for note in reader.notes)
        red = np.stack(list(reader.frames(0, 8)))
    with open_frames(VIDEO, channel="green") as reader:
        green = np.stack(list(reader.frames(0, 8)))
    assert _fruit(red).mean() > 5 * _fruit(green).mean()  # the red laser's speckle is in red


def test_colour_without_a_channel_is_refused_naming_the_option() -> None:
    with pytest.raises(DataError, match=r"--channel red\|green\|blue\|luma"), open_frames(VIDEO) as reader:
        next(iter(reader.frames()))


def test_the_fruit_decorrelates_as_biospeckle_does() -> None:
    # a living fruit's speckle decorrelates over tenths of a second: S1 grows with the lag and the
    # region's τc is measured inside the fitted lags (not 'above', not 'no signal')
    with open_frames(VIDEO, channel="red") as reader:
        fruit = _fruit(np.stack(list(reader.frames(0, 128))))
    activity = [float(s1(fruit, lag).mean()) for lag in (1, 5, 20)]
    assert activity[0] < activity[1] < activity[2], activity
    assert activity[2] > 2 * activity[0]
    tau = tau_c(fruit, max_lag=40, mask=np.ones(fruit.shape[1:], bool))
    assert 3.0 < float(tau) < 40.0, float(tau)


def test_analyze_takes_the_video_with_a_channel_and_warns_about_its_codec(tmp_path: Path,
                                                                        capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "s1.npy"
    code = main(["analyze", str(VIDEO), "--channel", "red", "--estimator", "s1", "--window", "32", "--lag", "2",
                 "-o", str(out), "--json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    result = json.loads(captured.out)
    assert result["shape"] == [614, 1092] and np.load(out).shape == (614, 1092)
    assert "h264" in captured.err
