"""Outputs are written whole or not at all (edgedsm.imageio.write_atomic): what analyze's -o and
--png leave when writing fails half-way (issue 34: nothing half-written)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from edgedsm.frameio.recording import WriteFailed
from edgedsm.imageio import ImageIOError, save_map_png, write_atomic


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
