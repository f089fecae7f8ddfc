"""Videos written by OpenCV's VideoWriter: lossless (FFV1, raw) read back exactly, lossy (MJPG)
read with a note naming the codec, colour by channel, truncated files named."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from edgedsm.frameio import ReaderError, open_frames


def _video(path, frames, fourcc, fps=25.0):
    colour = frames.ndim == 4
    code = 0 if fourcc == "raw" else cv2.VideoWriter.fourcc(*fourcc)
    writer = cv2.VideoWriter(str(path), cv2.CAP_FFMPEG, code, fps, (frames.shape[2], frames.shape[1]),
                             isColor=colour)
    assert writer.isOpened(), fourcc
    for frame in frames:
        writer.write(frame)
    writer.release()
    return path


def _speckle(count=8, shape=(32, 48), colour=False, seed=0):
    size = (count, *shape, 3) if colour else (count, *shape)
    return np.random.default_rng(seed).integers(0, 256, size, dtype=np.uint8)


@pytest.mark.parametrize(("fourcc", "name"), [("FFV1", "v.avi"), ("raw", "v.avi"), ("FFV1", "v.mkv")])
def test_lossless_videos_read_back_exactly(tmp_path, fourcc, name):
    frames = _speckle()
    with open_frames(_video(tmp_path / name, frames, fourcc)) as reader:
        assert reader.kind == "video" and reader.shape == (32, 48) and reader.dtype == np.uint8
        assert reader.dt == pytest.approx(0.04) and reader.lossy is None and not reader.notes
        assert reader.count == (None if name.endswith(".mkv") else 8)  # MKV stores a duration only
        assert np.array_equal(np.stack(list(reader.frames())), frames)
        assert np.array_equal(reader.window(5, 3), frames[5:8])  # seeks back, decodes forward


def test_a_lossy_video_is_analysed_with_a_note_naming_its_codec(tmp_path):
    frames = _speckle()
    with open_frames(_video(tmp_path / "m.avi", frames, "MJPG")) as reader:
        got = np.stack(list(reader.frames()))
        assert reader.lossy == "MJPG" and "'MJPG' is lossy" in reader.notes[0]
    assert got.shape == frames.shape and not np.array_equal(got, frames)


def test_a_colour_video_gives_each_channel(tmp_path):
    bgr = _speckle(count=4, colour=True)
    path = _video(tmp_path / "c.avi", bgr, "FFV1")
    with pytest.raises(ReaderError, match=r"c\.avi is colour.*--channel"):
        open_frames(path)
    for channel, index in (("red", 2), ("green", 1), ("blue", 0)):
        with open_frames(path, channel) as reader:
            assert np.array_equal(np.stack(list(reader.frames())), bgr[..., index]), channel


@pytest.mark.parametrize("fourcc", ["FFV1", "MJPG"])
def test_a_truncated_video_is_named(tmp_path, fourcc):
    path = _video(tmp_path / "full.avi", _speckle(count=40, shape=(48, 64)), fourcc)
    cut = tmp_path / "cut.avi"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size * 6 // 10])
    with pytest.raises(ReaderError, match=r"cut\.avi: ends after \d+ of the 40 frames"), open_frames(cut) as reader:
        for _ in reader.frames():
            pass


def test_not_a_video_is_named(tmp_path):
    path = tmp_path / "fake.mp4"
    path.write_bytes(b"\x00" * 100)
    with pytest.raises(ReaderError, match=r"fake\.mp4: cannot be opened as a video"):
        open_frames(path)


def test_a_16_bit_grey_video_stays_16_bit(tmp_path):
    frames = np.random.default_rng(2).integers(0, 4096, (5, 32, 48)).astype(np.uint16)
    path = tmp_path / "deep.mkv"
    writer = cv2.VideoWriter(str(path), cv2.CAP_FFMPEG, cv2.VideoWriter.fourcc(*"FFV1"), 10.0, (48, 32),
                             [cv2.VIDEOWRITER_PROP_DEPTH, cv2.CV_16U, cv2.VIDEOWRITER_PROP_IS_COLOR, 0])
    assert writer.isOpened()
    for frame in frames:
        writer.write(frame)
    writer.release()
    with open_frames(path) as reader:
        assert reader.dtype == np.uint16 and reader.bits == 16 and reader.lossy is None
        assert np.array_equal(np.stack(list(reader.frames())), frames)
        assert np.array_equal(reader.window(2, 2), frames[2:4])
