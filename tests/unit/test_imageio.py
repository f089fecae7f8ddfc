"""Outputs are written whole or not at all (edgedsm.imageio.write_atomic): what analyze's -o and
--png leave when writing fails half-way (issue 34: nothing half-written)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from edgedsm.frameio.recording import WriteFailed
from edgedsm.imageio import ImageIOError, MapAxes, colour_picture, render_map, save_map_png, write_atomic


def test_a_failed_write_leaves_the_old_file_and_no_partial_one(tmp_path):
    target = tmp_path / "map.npy"
    np.save(target, np.arange(4.0))

    def half_then_fail(file):
        file.write(b"\x93NUMPY half")
        raise RuntimeError("stopped half-way")

    with pytest.raises(RuntimeError, match="half-way"):
        write_atomic(target, half_then_fail)
    assert np.array_equal(np.load(target), np.arange(4.0))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.npy"]


def test_a_disk_refusal_is_write_failed_with_nothing_left(tmp_path):
    def full(file):
        raise OSError(28, "No space left on device")

    with pytest.raises(WriteFailed, match=r"new\.npy: cannot be written: No space left on device") as failed:
        write_atomic(tmp_path / "new.npy", full)
    assert failed.value.exit_code == 74 and list(tmp_path.iterdir()) == []


def test_a_complete_write_replaces_the_file(tmp_path):
    values = np.random.default_rng(0).random((5, 6))
    path = write_atomic(tmp_path / "sub" / "m.npy", lambda file: np.save(file, values))
    assert np.array_equal(np.load(path), values) and [p.name for p in path.parent.iterdir()] == ["m.npy"]


def test_map_pictures_are_written_atomically_and_decode(tmp_path):
    path = save_map_png(tmp_path / "m.png", np.linspace(0, 1, 64 * 64).reshape(64, 64), title="t")
    picture = cv2.imread(str(path))
    assert picture is not None and picture.shape[0] > 384 and [p.name for p in tmp_path.iterdir()] == ["m.png"]
    with pytest.raises(ImageIOError, match="no image format"):
        save_map_png(tmp_path / "m.unknown", np.zeros((4, 4)))
    assert [p.name for p in tmp_path.iterdir()] == ["m.png"]


def test_one_colour_renderer_draws_the_same_pixels_for_home_assistant_the_dashboard_and_the_pictures(tmp_path):
    from edgedsm.dashboard.maps import colour_bar_png, colour_png
    from edgedsm.imageio import COLORMAPS, colour_picture, colour_ramp
    from edgedsm.publish.colormap import render_colour_map

    # a map with every index of the scale, its extremes included (low → index 0, high → 255)
    values = np.random.default_rng(3).random((48, 64)) * 0.5 + 0.1
    reference, low, high = colour_picture(values, "viridis")
    assert (low, high) == (values.min(), values.max())
    lut = cv2.applyColorMap(np.arange(256, dtype=np.uint8)[:, None], COLORMAPS["viridis"])[:, 0]
    expected = lut[np.clip(np.rint((values - low) * 255 / (high - low)), 0, 255).astype(int)]
    assert np.array_equal(reference, expected)
    # the dashboard's map and colour bar
    dashboard = cv2.imdecode(np.frombuffer(colour_png(values), np.uint8), cv2.IMREAD_COLOR)
    assert np.array_equal(dashboard, reference)
    bar = cv2.imdecode(np.frombuffer(colour_bar_png(256, 16), np.uint8), cv2.IMREAD_COLOR)
    assert np.array_equal(bar, colour_ramp(256, 16, "viridis"))
    assert np.array_equal(bar[0, 0], lut[255]) and np.array_equal(bar[-1, 0], lut[0])
    # Home Assistant's picture: the same pixels left of its colour bar, and the same bar
    ha = render_colour_map(values, colormap="viridis", max_size=None)
    assert np.array_equal(ha[:48, :64], reference)
    # the saved picture (analyze --png, demo, watch): the same pixels, zoomed 6x, at the same range
    path = save_map_png(tmp_path / "m.png", values, value_range=(low, high))
    saved = cv2.imread(str(path))
    zoom = 384 // 64
    assert np.array_equal(saved[28:28 + 48 * zoom:zoom, 0:64 * zoom:zoom], reference)
    # the other colour maps the config accepts go through the same code
    for name in COLORMAPS:
        ha = render_colour_map(values, colormap=name, max_size=None)
        assert np.array_equal(ha[:48, :64], colour_picture(values, name)[0])


def test_a_map_of_camera_pixels_carries_a_50_px_scale_bar_and_no_axis_labels():
    picture = render_map(np.random.default_rng(1).random((64, 64)), title="S2  N=64", unit="grey")
    assert "50 px" in picture.texts and picture.texts[-2] == "S2  N=64"
    zoom = 384 // 64  # the bar is 50 camera pixels long at the picture's zoom (its round caps add 2 px a side)
    row = (picture.canvas[28 + 64 * zoom + 14, :4 + 50 * zoom + 3] == 0).all(axis=1)
    black = np.flatnonzero(row)
    assert 50 * zoom < black.size <= 50 * zoom + 5 and black.size == black.max() - black.min() + 1


def test_a_map_whose_axes_are_not_space_says_what_they_are_without_a_pixel_bar():
    axes = MapAxes(x="time (frames)", y="position along the row (px)", x_range=(2, 61), y_range=(0, 39))
    values = np.random.default_rng(2).random((40, 60))
    picture = render_map(values, title="THSP row 4", axes=axes)
    assert not any("px" in text and text != axes.y for text in picture.texts)  # no "50 px" scale bar
    for text in ("time (frames)", "position along the row (px)", "2", "61", "0", "39", "THSP row 4"):
        assert text in picture.texts
    # each axis stretched to at least 256 px on its own (40 rows x 7, 60 columns x 5)
    canvas, left, top = picture.canvas, 64, 28
    reference, _, _ = colour_picture(values, "viridis", tuple(np.percentile(values, [1, 99])))
    assert np.array_equal(canvas[top:top + 280:7, left:left + 300:5], reference)
    # the y label is drawn (dark pixels) in its strip left of the values, the x label below the picture
    assert (canvas[top:top + 280, 0:22] < 128).sum() > 100
    assert (canvas[top + 280 + 24:top + 280 + 44, left:left + 300] < 128).sum() > 100


def test_a_y_label_longer_than_a_short_picture_is_drawn_smaller_not_cut():
    axes = MapAxes(x="t", y="a rather long label for a short picture", x_range=(0, 1), y_range=(0, 1))
    strip_full = render_map(np.zeros((300, 300)), axes=axes).canvas[28:28 + 300, 0:22]
    dark_rows = np.flatnonzero((strip_full < 128).any(axis=(1, 2)))
    assert dark_rows.size and dark_rows.min() > 0 and dark_rows.max() < 299  # whole, inside the picture
