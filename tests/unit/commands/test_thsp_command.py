"""`edgedsm thsp`: the THSP and COM of one row or column from any input analyze reads, IM and AVD
printed and in JSON, pictures written, and a line outside the frames as one line with exit 65."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile

from edgedsm.cli import main
from edgedsm.estimators import s1
from edgedsm.estimators.descriptors import im


def _frames(dtype: type = np.uint8, top: int = 255) -> np.ndarray:
    return np.random.default_rng(11).integers(0, top + 1, (18, 9, 13)).astype(dtype)


def test_thsp_of_a_row_from_npy(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    frames = _frames()
    np.save(tmp_path / "f.npy", frames)
    out = tmp_path / "out"
    assert main(["thsp", str(tmp_path / "f.npy"), "--row", "4", "--start", "2", "--window", "12", "-o", str(out),
                 "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    used = frames[2:14]
    np.testing.assert_array_equal(np.load(out / "thsp.npy"), used[:, 4, :].T)
    com = np.load(out / "com.npy")
    assert com.shape == (256, 256) and com.sum() == 13 * 11
    # for 8-bit data the COM's moments are the row's means of IM and S1 at m = 1
    assert result["im"] == pytest.approx(im(used, 1)[4].mean(), rel=1e-15)
    assert result["avd"] == pytest.approx(s1(used, 1)[4].mean(), rel=1e-15)
    assert result["thsp_shape"] == [13, 12] and result["com_divisor"] == 1
    for name in ("thsp.png", "com.png"):
        picture = cv2.imread(str(out / name))
        assert picture is not None and picture.std() > 0


def test_thsp_of_a_column_of_a_16_bit_tiff_uses_8_bit_levels(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                                             ) -> None:
    frames = _frames(np.uint16, 65535)
    tifffile.imwrite(tmp_path / "f.tif", frames)
    out = tmp_path / "out"
    assert main(["thsp", str(tmp_path / "f.tif"), "--column", "12", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    np.testing.assert_array_equal(np.load(out / "thsp.npy"), frames[:, :, 12].T)
    eight = (frames[:, :, 12] // 256).astype(np.uint8)
    expected = np.mean((eight[1:].astype(float) - eight[:-1]) ** 2)
    assert f"IM {expected:.6g} grey levels²" in text and "(8-bit levels: 16-bit data / 256)" in text


def test_a_row_outside_the_frames_is_one_line_with_exit_65(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                                           ) -> None:
    np.save(tmp_path / "f.npy", _frames())
    assert main(["thsp", str(tmp_path / "f.npy"), "--row", "9", "-o", str(tmp_path / "out")]) == 65
    err = capsys.readouterr().err
    assert err.strip().splitlines() == [f"edgedsm: bad data: {tmp_path / 'f.npy'}: row 9 is outside its 9x13 frames "
                                        "(rows 0..8)"]
    assert main(["thsp", str(tmp_path / "f.npy"), "--column", "-1", "-o", str(tmp_path / "out")]) == 65
    assert not (tmp_path / "out").exists()


def test_row_or_column_is_required(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stop:
        main(["thsp", "f.npy", "-o", str(tmp_path)])
    assert stop.value.code == 2 and "one of the arguments --row --column is required" in capsys.readouterr().err


def test_the_pictures_name_their_axes_time_position_and_grey_levels_without_a_pixel_bar(tmp_path: Path) -> None:
    from edgedsm.commands.thsp import com_axes, thsp_axes
    from edgedsm.imageio import render_map

    frames = _frames()
    np.save(tmp_path / "f.npy", frames)
    out = tmp_path / "out"
    assert main(["thsp", str(tmp_path / "f.npy"), "--column", "3", "--start", "2", "--window", "12", "-o",
                 str(out)]) == 0
    image, com = np.load(out / "thsp.npy"), np.load(out / "com.npy")
    axes = thsp_axes("column", 9, 2, 13)
    assert (axes.x, axes.y, axes.x_range, axes.y_range) == ("time (frames)", "position along the column (px)",
                                                            (2, 13), (0, 8))
    drawn = render_map(image, "THSP column 3", unit="grey levels", axes=axes)
    # the file is that picture, pixel for pixel: its texts are the ones checked here
    assert np.array_equal(cv2.imread(str(out / "thsp.png")), drawn.canvas)
    assert {"time (frames)", "position along the column (px)", "2", "13", "0", "8"} <= set(drawn.texts)
    assert not any(text.endswith(" px") for text in drawn.texts)
    levels = com_axes(1)
    assert (levels.x, levels.y, levels.x_range) == ("grey level at t+1", "grey level at t", (0, 255))
    top = max(float(np.log1p(com.max())), 1.0)
    drawn = render_map(np.log1p(com), "COM column 3: log(1 + count)", value_range=(0.0, top), axes=levels)
    assert np.array_equal(cv2.imread(str(out / "com.png")), drawn.canvas)
    assert {"grey level at t+1", "grey level at t", "255"} <= set(drawn.texts) and "50 px" not in drawn.texts
    assert com_axes(256).y == "grey level / 256 at t"  # 16-bit data: the COM's levels are its top 8 bits
