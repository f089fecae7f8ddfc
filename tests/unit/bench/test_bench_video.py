"""`edgedsm bench video`'s parts: a child decodes a file and judges it against the frames written
(bit-exact or not, in numbers), and the table says which decoder died of what."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from edgedsm_lab.bench.dib import dib_avi
from edgedsm_lab.bench.video import child, rows_for, speckle, write_video


@pytest.mark.parametrize("decoder", ["PyAV", "edgedsm (PyAV)"])
def test_a_child_judges_a_16_bit_video_bit_exact(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                 decoder: str) -> None:
    frames = speckle(4, 16, deep=True)
    assert frames.dtype == np.uint16 and frames.max() < 4096
    np.save(tmp_path / "f.npy", frames)
    write_video(tmp_path / "f.mkv", frames, "ffv1", "gray16le", "gray16le")
    child(decoder, str(tmp_path / "f.mkv"), str(tmp_path / "f.npy"))
    result = json.loads(capsys.readouterr().out)
    assert (result["frames"], result["dtype"], result["exact"], result["mae"]) == (4, "uint16", True, 0.0)


def test_pyav_asked_for_grey_is_not_exact_on_a_palette_but_edgedsm_is(tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    # swscale's pal8 -> gray goes through luma weights and rounds: some levels come back one off
    frames = np.tile(np.arange(256, dtype=np.uint8).reshape(16, 16), (3, 1, 1))
    np.save(tmp_path / "f.npy", frames)
    dib_avi(tmp_path / "f.avi", frames, 8)
    results = {}
    for decoder in ("PyAV", "edgedsm (PyAV)"):
        child(decoder, str(tmp_path / "f.avi"), str(tmp_path / "f.npy"))
        results[decoder] = json.loads(capsys.readouterr().out)
    assert results["edgedsm (PyAV)"]["exact"] is True
    assert results["PyAV"]["exact"] is False and 0 < results["PyAV"]["mae"] < 1


def test_the_table_names_a_decoder_that_died() -> None:
    results = {"OpenCV (BGR)": {"frames": 10, "seconds": 0.5, "dtype": "uint8", "exact": True, "mae": 0.0},
               "OpenCV (unconverted)": {"died": "SIGABRT"},
               "PyAV": {"frames": 10, "seconds": 1.0, "dtype": "uint8", "exact": False, "mae": 0.125},
               "edgedsm (PyAV)": {"frames": 10, "seconds": 0.25, "dtype": "uint8", "exact": True, "mae": 0.0}}
    rows = rows_for("raw grey 8-bit AVI", results, 10)
    assert rows[0][2:] == ["20 (10 frames)", "1.00", "uint8", "bit-exact"]
    assert rows[1][2] == "died: SIGABRT"
    assert rows[2][2:] == ["10 (10 frames)", "0.50", "uint8", "no (mean error 0.125)"]
    assert rows[3][3] == "2.00"
