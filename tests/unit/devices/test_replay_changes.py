"""The replay camera when its recording changes under it (issue 34): an .npy, a TIFF recording
or an image in a folder truncated or replaced mid-replay ends the stream with ``DataError`` naming
the file (the daemon then switches the laser off and exits 65), never a signal."""

from __future__ import annotations

import os

import cv2
import numpy as np
import pytest
import tifffile

from edgedsm.devices.camera.replay import ReplayCamera
from edgedsm.errors import DataError
from tests.hostile_files import png_bytes

FRAMES = np.random.default_rng(4).integers(0, 256, (40, 32, 32), dtype=np.uint8)


def _take(frames, count: int) -> list[np.ndarray]:
    return [next(frames).pixels for _ in range(count)]


def test_an_npy_truncated_mid_replay(tmp_path):
    path = tmp_path / "r.npy"
    np.save(path, FRAMES)
    with ReplayCamera(path) as camera:
        frames = camera.frames()
        assert np.array_equal(np.stack(_take(frames, 5)), FRAMES[:5])
        os.truncate(path, path.stat().st_size - 32 * 32 * 10)  # the last ten frames gone
        with pytest.raises(DataError, match=r"r\.npy: frame 5 cannot be read: it changed while being read"):
            next(frames)


def test_a_tiff_recording_truncated_mid_replay(tmp_path):
    path = tmp_path / "r.tif"
    with tifffile.TiffWriter(path) as writer:
        for frame in FRAMES:
            writer.write(frame, compression="zlib", contiguous=False)
    with ReplayCamera(path) as camera:
        frames = camera.frames()
        assert np.array_equal(np.stack(_take(frames, 5)), FRAMES[:5])
        os.truncate(path, path.stat().st_size // 2)
        with pytest.raises(DataError, match=r"r\.tif: page \d+ cannot be decoded"):
            _take(frames, 40)


def test_an_image_replaced_by_a_lying_one_mid_replay(tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    for index, frame in enumerate(FRAMES[:6]):
        assert cv2.imwrite(str(folder / f"f_{index:03d}.png"), frame)
    with ReplayCamera(folder) as camera:
        frames = camera.frames()
        assert np.array_equal(np.stack(_take(frames, 2)), FRAMES[:2])
        (folder / "f_003.png").write_bytes(png_bytes(2 ** 16, 2 ** 16))
        got = _take(frames, 1)
        assert np.array_equal(got[0], FRAMES[2])
        with pytest.raises(DataError, match=r"f_003\.png: the PNG header claims frames of 65536 x 65536"):
            next(frames)
