"""The memory-budget rule (edgedsm/frameio/budget.py) and the header-only image sizes it reads."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import tifffile

from edgedsm.frameio import ReaderError, budget, open_frames
from edgedsm.frameio.budget import (
    MAX_FRAME_PIXELS,
    BudgetError,
    check_bytes,
    check_count,
    check_frame,
    check_image,
    image_size,
)
from tests.hostile_files import bmp_bytes, npy_bytes, png_bytes


def test_the_pixel_bound_is_exact():
    assert check_frame("f", (2 ** 14, 2 ** 14), 1) == 2 ** 28  # 16384 x 16384: allowed
    with pytest.raises(BudgetError, match=r"16384 x 16385 = 268,451,840 pixels, more than the 268,435,456 \(2\^28\)"):
        check_frame("f", (2 ** 14, 2 ** 14 + 1), 1)
    assert MAX_FRAME_PIXELS == 2 ** 28


@pytest.mark.parametrize("shape", [(0, 5), (5, 0), (-1, 5), (5, -3), (7,), (4, 4, 0)])
def test_empty_and_negative_sizes_are_not_frames(shape):
    with pytest.raises(BudgetError, match="not a frame size"):
        check_frame("f", shape, 1)


def test_an_allocation_over_half_the_available_memory_is_refused(monkeypatch):
    monkeypatch.setattr(budget, "available_bytes", lambda: 100 * 2 ** 20)  # 100 MiB available
    check_bytes("f", "x", 50 * 2 ** 20)
    with pytest.raises(BudgetError, match=r"would take 50 MiB, more than the 50 MiB allowed \(50% of the memory"):
        check_bytes("f", "x", 50 * 2 ** 20 + 1)
    # a 4096 x 4096 float64 frame (128 MiB) is within the pixel bound but not this machine's memory
    with pytest.raises(BudgetError, match="a frame of 4096 x 4096 pixels"):
        check_frame("f", (4096, 4096), 8)


def test_available_memory_is_read_from_the_machine():
    available = budget.available_bytes()
    assert 2 ** 24 < available < 2 ** 50


def test_a_window_beyond_the_budget_is_refused_before_it_is_allocated(tmp_path, monkeypatch):
    np.save(tmp_path / "s.npy", np.zeros((40, 64, 64), np.uint8))
    with open_frames(tmp_path / "s.npy") as reader:
        monkeypatch.setattr(budget, "available_bytes", lambda: 2 * 20 * 64 * 64)  # room for 20 frames
        assert reader.window(0, 20).shape == (20, 64, 64)
        with pytest.raises(ReaderError, match="a window of 21 frames would take"):
            reader.window(0, 21)


def test_zero_frame_counts_are_refused():
    check_count("f", 1)
    with pytest.raises(BudgetError, match="claims 0 frames"):
        check_count("f", 0)


@pytest.mark.parametrize(("suffix", "image", "expected"), [
    (".png", np.zeros((37, 53), np.uint8), (37, 53, 1, 1, "PNG")),
    (".png", np.zeros((37, 53, 3), np.uint16), (37, 53, 3, 2, "PNG")),
    (".bmp", np.zeros((37, 53), np.uint8), (37, 53, 3, 1, "BMP")),
    (".jpg", np.zeros((37, 53), np.uint8), (37, 53, 1, 1, "JPEG")),
    (".pgm", np.zeros((37, 53), np.uint16), (37, 53, 1, 2, "PNM")),
    (".ppm", np.zeros((37, 53, 3), np.uint8), (37, 53, 3, 1, "PNM")),
    (".tif", np.zeros((37, 53), np.uint16), (37, 53, 1, 2, "TIFF")),
])
def test_image_sizes_from_the_headers_opencv_writes(tmp_path, suffix, image, expected):
    path = tmp_path / f"a{suffix}"
    assert cv2.imwrite(str(path), image)
    size = image_size(path)
    assert size is not None and (size.rows, size.columns, size.samples, size.itemsize, size.format) == expected
    decoded = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    assert decoded.shape[:2] == size.shape  # the header's size is the decoded one


def test_tiff_sizes_from_tifffile_and_bmp_top_down(tmp_path):
    tifffile.imwrite(tmp_path / "c.tif", np.zeros((3, 21, 17), np.uint16), photometric="rgb", planarconfig="separate")
    size = image_size(tmp_path / "c.tif")
    assert size is not None and (size.rows, size.columns, size.samples, size.itemsize) == (21, 17, 3, 2)
    (tmp_path / "t.bmp").write_bytes(bmp_bytes(30, -20))
    size = image_size(tmp_path / "t.bmp")
    assert size is not None and size.shape == (20, 30)


def test_a_lying_header_is_refused_with_its_claim(tmp_path):
    (tmp_path / "huge.png").write_bytes(png_bytes(2 ** 15, 2 ** 15, depth=16, colour=6))
    with pytest.raises(BudgetError, match=r"huge\.png: the PNG header claims frames of 32768 x 32768 x 4 = "
                                          r"1,073,741,824 pixels"):
        check_image(tmp_path / "huge.png")
    (tmp_path / "huge.npy").write_bytes(npy_bytes("<u2", (3, 2 ** 15, 2 ** 15)))
    with pytest.raises(BudgetError, match="1,073,741,824 pixels"):
        open_frames(tmp_path / "huge.npy")


def test_content_decides_not_the_name(tmp_path):
    assert cv2.imwrite(str(tmp_path / "a.png"), np.zeros((5, 7), np.uint8))
    (tmp_path / "a.png").rename(tmp_path / "really_png.bmp")
    size = image_size(tmp_path / "really_png.bmp")
    assert size is not None and size.format == "PNG" and size.shape == (5, 7)
    (tmp_path / "text.png").write_text("P5 is not enough")
    assert image_size(tmp_path / "text.png") is None
