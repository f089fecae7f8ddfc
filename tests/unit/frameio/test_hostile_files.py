"""The hostile-file corpus (tests/hostile_files.py) against every reader: ``open_frames`` (npy,
TIFF, image folder), the replay camera, a TIFF or an .npy inside an image folder, and region
masks. Every case is refused with the reader's error (exit 65, 66 for a missing path) naming the
file, before anything the header claims is allocated: the Python heap's peak stays under 1 MiB
for headers claiming gigabytes.
"""

from __future__ import annotations

import shutil
import tracemalloc

import numpy as np
import pytest
import tifffile  # also imported here, not first inside a measured read

from edgedsm.devices.camera.replay import ReplayCamera, first_frame_shape
from edgedsm.errors import DataError, DeviceError
from edgedsm.frameio import ReaderError, open_frames
from edgedsm.frameio.npy import NpyReader
from edgedsm.frameio.tiff import TiffReader
from edgedsm.geometry import load_mask_image, load_mask_image_or_none
from tests import hostile_files
from tests.hostile_files import CASES

NAMES = sorted(CASES)


@pytest.mark.parametrize("name", NAMES)
def test_every_case_is_refused_in_one_line_naming_the_file(tmp_path, name):
    write, code, fragment = CASES[name]
    path = write(tmp_path)
    tracemalloc.start()
    try:
        with pytest.raises(ReaderError) as refused, open_frames(path) as reader:
            list(reader.frames())
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    message = str(refused.value)
    assert refused.value.exit_code == code
    assert fragment in message and "\n" not in message
    assert message.startswith(str(path.parent))  # the file (or its folder's file) first
    assert peak < 2 ** 20, f"{peak:,} bytes allocated before refusing"


@pytest.mark.parametrize("name", [n for n in NAMES if n.startswith("npy_")])
def test_the_npy_reader_itself_refuses_each_npy_case(tmp_path, name):
    write, _, fragment = CASES[name]
    with pytest.raises(ReaderError, match=fragment.replace("(", r"\(").replace(")", r"\)")):
        NpyReader(write(tmp_path))


@pytest.mark.parametrize("name", [n for n in NAMES if n.startswith("tiff_")])
def test_the_tiff_reader_itself_refuses_each_tiff_case(tmp_path, name):
    write, _, fragment = CASES[name]
    with pytest.raises(ReaderError) as refused:
        TiffReader(write(tmp_path))
    assert fragment in str(refused.value)


@pytest.mark.parametrize("name", [n for n in NAMES if n.startswith(("npy_", "tiff_", "folder_"))])
def test_the_replay_camera_and_check_config_refuse_each_case(tmp_path, name):
    path = CASES[name][0](tmp_path)
    with pytest.raises(DataError):
        ReplayCamera(path).open()
    with pytest.raises(DataError):
        first_frame_shape(path)  # what check-config asks of a replay: URI


def test_a_missing_replay_is_a_device_error_and_no_shape(tmp_path):
    with pytest.raises(DeviceError, match="no such file"):
        ReplayCamera(tmp_path / "gone.npy").open()
    with pytest.raises(ReaderError, match="no such file") as missing:
        first_frame_shape(tmp_path / "gone.npy")
    assert missing.value.exit_code == 66


@pytest.mark.parametrize("name", [n for n in NAMES if n.startswith("tiff_")])
def test_a_hostile_tiff_inside_an_image_folder_is_refused_or_read_as_what_it_holds(tmp_path, name):
    source = CASES[name][0](tmp_path)
    folder = tmp_path / "folder"
    folder.mkdir()
    shutil.copy(source, folder / "f_000.tif")
    try:
        with open_frames(folder) as reader:
            frames = list(reader.frames())
    except ReaderError as exc:
        assert str(folder / "f_000.tif") in str(exc)
    else:  # OpenCV decodes what the strip holds: a real 64 x 64 frame, nothing larger
        assert name == "tiff_strip_beyond_end" and [f.shape for f in frames] == [(64, 64)]


def test_masks_claiming_too_much_are_refused_before_decoding(tmp_path):
    masks = hostile_files.mask_cases(tmp_path)
    for name in ("png_huge", "bmp_huge"):
        tracemalloc.start()
        try:
            with pytest.raises(DataError, match="header of the mask claims frames of") as refused:
                load_mask_image_or_none(masks[name])
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert refused.value.exit_code == 65 and str(masks[name]) in str(refused.value) and peak < 2 ** 20
    for name in ("empty", "garbage"):
        assert load_mask_image_or_none(masks[name]) is None
    assert load_mask_image_or_none(tmp_path / "absent.png") is None


def test_a_real_mask_still_loads(tmp_path):
    import cv2

    image = np.zeros((40, 60), np.uint8)
    image[10:30, 20:50] = 255
    assert cv2.imwrite(str(tmp_path / "m.png"), image)
    mask = load_mask_image(tmp_path / "m.png", (20, 30))
    assert mask.shape == (20, 30) and int(mask.sum()) == 10 * 15


def test_a_real_deflate_bomb_written_by_tifffile_is_refused_from_its_tags(tmp_path):
    """20000 x 20000 zeros (400 MB decoded) in deflate tiles, as tifffile writes them: a file of
    about a megabyte that must be refused from its tags, not decoded."""
    tile = np.zeros((2048, 2048), np.uint8)
    tiles = (tile for _ in range(10 * 10))
    path = tmp_path / "bomb.tif"
    tifffile.imwrite(path, tiles, shape=(20000, 20000), dtype=np.uint8, tile=(2048, 2048), compression="zlib")
    assert path.stat().st_size < 2 ** 21
    tracemalloc.start()
    try:
        with pytest.raises(ReaderError, match=r"20000 x 20000 x 1 = 400,000,000 pixels, more than the 268,435,456"):
            open_frames(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 2 ** 21
