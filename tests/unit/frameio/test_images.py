"""Image folders and printf patterns, written by OpenCV: natural numeric order, colour channels,
16-bit depth, one odd-sized image named before anything is read."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from edgedsm.frameio import InputMissing, ReaderError, open_frames
from edgedsm.frameio.images import natural_key


def _numbered(folder, frames, name="img_{}.bmp", first=1):
    folder.mkdir(exist_ok=True)
    for index, frame in enumerate(frames):
        assert cv2.imwrite(str(folder / name.format(index + first)), frame)
    return folder


def test_natural_key_orders_numbers_as_numbers():
    names = ["img_10.bmp", "img_2.bmp", "img_1.bmp", "img_100.bmp", "IMG_3.bmp"]
    assert sorted(names, key=natural_key) == ["img_1.bmp", "img_2.bmp", "IMG_3.bmp", "img_10.bmp", "img_100.bmp"]


def test_a_folder_img_1_to_img_12_reads_in_numeric_order(tmp_path):
    # each frame's grey level is its number: name order would give 1, 10, 11, 12, 2, ...
    frames = [np.full((6, 8), 10 * (i + 1), np.uint8) for i in range(12)]
    folder = _numbered(tmp_path / "series", frames)
    with open_frames(folder) as reader:
        assert reader.kind == "folder" and reader.count == 12 and reader.shape == (6, 8)
        assert [int(f[0, 0]) for f in reader.frames()] == [10 * (i + 1) for i in range(12)]
        assert [int(f[0, 0]) for f in reader.frames(9)] == [100, 110, 120]
        assert reader.window(3, 2)[:, 0, 0].tolist() == [40, 50]


def test_a_pattern_reads_its_files_only_and_notes_missing_numbers(tmp_path):
    folder = tmp_path / "seq"
    _numbered(folder, [np.full((4, 4), v, np.uint8) for v in (1, 2, 3)], name="f_{:04d}.png", first=0)
    cv2.imwrite(str(folder / "f_0005.png"), np.full((4, 4), 5, np.uint8))
    cv2.imwrite(str(folder / "other_0004.png"), np.full((4, 4), 99, np.uint8))
    with open_frames(folder / "f_%04d.png") as reader:
        assert [int(f[0, 0]) for f in reader.frames()] == [1, 2, 3, 5]
        assert any("2 numbers missing" in note and "(3, 4)" in note for note in reader.notes)


def test_16_bit_pngs_stay_16_bit(tmp_path):
    frames = [np.random.default_rng(i).integers(0, 4096, (5, 7), dtype=np.uint16) for i in range(3)]
    with open_frames(_numbered(tmp_path / "deep", frames, name="{}.png")) as reader:
        got = list(reader.frames())
    assert reader.dtype == np.uint16 and reader.bits == 16
    assert all(np.array_equal(a, b) for a, b in zip(got, frames, strict=True))


def test_a_colour_folder_gives_each_channel_and_refuses_none(tmp_path):
    rng = np.random.default_rng(3)
    bgr = [rng.integers(0, 256, (6, 9, 3), dtype=np.uint8) for _ in range(4)]
    folder = _numbered(tmp_path / "colour", bgr)
    for channel, index in (("red", 2), ("green", 1), ("blue", 0)):
        with open_frames(folder, channel) as reader:
            got = list(reader.frames())
        assert all(np.array_equal(g, b[:, :, index]) for g, b in zip(got, bgr, strict=True)), channel
    with open_frames(folder, "luma") as reader:
        luma = next(reader.frames())
    assert np.abs(luma.astype(int) - cv2.cvtColor(bgr[0], cv2.COLOR_BGR2GRAY)).max() <= 1
    with pytest.raises(ReaderError, match=r"is colour \(3 channels\).*--channel red\|green\|blue\|luma"):
        open_frames(folder)


def test_grey_saved_as_colour_is_read_as_grey(tmp_path):
    grey = [np.full((4, 4, 3), v, np.uint8) for v in (5, 6)]
    with open_frames(_numbered(tmp_path / "g", grey, name="{}.png")) as reader:
        assert [int(f[0, 0]) for f in reader.frames()] == [5, 6] and reader.colour_order is None


def test_one_odd_sized_image_is_named_at_open(tmp_path):
    frames = [np.zeros((8, 8), np.uint8)] * 5
    folder = _numbered(tmp_path / "odd", frames)
    cv2.imwrite(str(folder / "img_4.bmp"), np.zeros((8, 10), np.uint8))
    with pytest.raises(ReaderError, match=r"img_4\.bmp: 8x10 frame among 8x8 ones"):
        open_frames(folder)


def test_empty_folders_unreadable_files_and_missing_paths(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(ReaderError, match="no images"):
        open_frames(tmp_path / "empty")
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / "1.png").write_bytes(b"not a png")
    with pytest.raises(ReaderError, match=r"1\.png: cannot be read as an image"):
        open_frames(broken)
    with pytest.raises(InputMissing):
        open_frames(tmp_path / "nowhere" / "%05d.png")
    with pytest.raises(InputMissing):
        open_frames(tmp_path / "nowhere.npy")
    with pytest.raises(ReaderError, match="exactly one %d"):
        open_frames(tmp_path / "%d_%d.png")
