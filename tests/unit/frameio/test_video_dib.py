"""Uncompressed DIB AVIs as older capture software writes them (palettized 8/4/1-bit, RGB555,
BGR24, bottom-up and top-down), written byte by byte (edgedsm_lab.bench.dib), and videos that
FFmpeg itself writes (PyAV's muxer): every pixel decoded is the one written, with row 0 on top;
a palette is looked up, never read as intensities. Then the hostile ones: each a ReaderError
naming the file (tests/hostile_video.py; OpenCV's reader used to abort the process on every DIB AVI, issue 34)."""

from __future__ import annotations

from pathlib import Path

import av
import numpy as np
import pytest

from edgedsm.frameio import ReaderError, open_frames
from tests.hostile_video import colour_palette, colours, dib_avi, expected, hostile_avis, indices

SHAPE = (7, 13)  # odd sizes: every row of a 1-, 4- or 8-bit DIB is padded to 4 bytes


@pytest.mark.parametrize("top_down", [False, True], ids=["bottom-up", "top-down"])
@pytest.mark.parametrize("bits", [8, 4, 1])
def test_a_grey_palette_gives_its_grey_levels(tmp_path, bits, top_down):
    frames = indices(4, *SHAPE, bits)
    path = dib_avi(tmp_path / "grey.avi", frames, bits, top_down=top_down)
    want = expected(frames, bits)[..., 0]  # the grey palette's level of each index
    with open_frames(path) as reader:
        assert (reader.count, reader.shape, reader.dtype, reader.bits) == (4, SHAPE, np.uint8, 8)
        assert reader.dt == pytest.approx(0.04) and reader.lossy is None and reader.colour_order is None
        got = np.stack(list(reader.frames()))
    assert np.array_equal(got, want)
    assert got[0, 0, 0] == want.max() and got[0, -1, -1] == 0  # the marked corner is on top, on the left
    if bits < 8:
        assert not np.array_equal(got, frames)  # levels, not indices (a 4-bit index 15 is level 240)


@pytest.mark.parametrize("top_down", [False, True], ids=["bottom-up", "top-down"])
@pytest.mark.parametrize("bits", [8, 4, 1])
def test_a_colour_palette_gives_colours_by_channel(tmp_path, bits, top_down):
    frames = indices(3, *SHAPE, bits, seed=1)
    palette = colour_palette(1 << bits)
    path = dib_avi(tmp_path / "colour.avi", frames, bits, palette, top_down=top_down)
    rgb = expected(frames, bits, palette)
    with pytest.raises(ReaderError, match=r"colour\.avi is colour \(3 channels\).*--channel"):
        open_frames(path)
    for channel, index in (("red", 0), ("green", 1), ("blue", 2)):
        with open_frames(path, channel) as reader:
            assert reader.colour_order == "rgb" and reader.dtype == np.uint8
            assert np.array_equal(np.stack(list(reader.frames())), rgb[..., index]), channel
    with open_frames(path, "luma") as reader:
        luma = np.stack(list(reader.frames())).astype(float)
    assert np.abs(luma - rgb @ np.array([0.299, 0.587, 0.114])).max() <= 0.5 + 1e-3


@pytest.mark.parametrize("top_down", [False, True], ids=["bottom-up", "top-down"])
@pytest.mark.parametrize(("bits", "top"), [(16, 31), (24, 255)], ids=["RGB555", "BGR24"])
def test_rgb555_and_bgr24_give_their_colours(tmp_path, bits, top, top_down):
    frames = colours(3, *SHAPE, top=top, seed=bits)
    path = dib_avi(tmp_path / "rgb.avi", frames, bits, top_down=top_down)
    rgb = expected(frames, bits)
    for channel, index in (("red", 0), ("green", 1), ("blue", 2)):
        with open_frames(path, channel) as reader:
            assert (reader.count, reader.shape, reader.dtype) == (3, SHAPE, np.uint8)
            assert np.array_equal(np.stack(list(reader.frames())), rgb[..., index]), channel
    if bits == 16:  # 5 bits widened to 8 as FFmpeg does: 31 -> 255, 16 -> 132
        assert set(np.unique(rgb)) <= {(v << 3) | (v >> 2) for v in range(32)}


def test_grey_stored_as_bgr24_is_read_as_grey(tmp_path):
    grey = indices(3, *SHAPE, 8, seed=4)
    path = dib_avi(tmp_path / "g24.avi", np.repeat(grey[..., None], 3, axis=3), 24)
    with open_frames(path) as reader:
        assert reader.colour_order is None
        assert np.array_equal(np.stack(list(reader.frames())), grey)


def test_window_seeks_back_and_reads_forward(tmp_path):
    frames = indices(9, *SHAPE, 8, seed=5)
    path = dib_avi(tmp_path / "w.avi", frames, 8)
    with open_frames(path) as reader:
        assert np.array_equal(reader.window(6, 3), frames[6:9])
        assert np.array_equal(reader.window(1, 2), frames[1:3])  # back: opened again, decoded forward
        with pytest.raises(ReaderError, match=r"w\.avi: .*frame"):
            reader.window(8, 4)


def _pyav_video(path: Path, frames: np.ndarray, codec: str, pix_fmt: str, source: str, rate: int = 25) -> Path:
    with av.open(str(path), "w") as container:
        stream = container.add_stream(codec, rate=rate)
        stream.width, stream.height, stream.pix_fmt = frames.shape[2], frames.shape[1], pix_fmt
        for image in frames:
            container.mux(stream.encode(av.VideoFrame.from_ndarray(image, format=source)))
        container.mux(stream.encode(None))
    return path


@pytest.mark.parametrize(("codec", "pix_fmt", "top", "name"), [
    ("ffv1", "gray16le", 65535, "deep.mkv"), ("ffv1", "gray12le", 4095, "twelve.mkv"),
    ("ffv1", "gray", 255, "grey.avi"), ("rawvideo", "gray", 255, "raw.avi"), ("ffv1", "gray16le", 65535, "deep.avi"),
])
def test_grey_videos_ffmpeg_writes_are_bit_exact(tmp_path, codec, pix_fmt, top, name):
    rng = np.random.default_rng(6)
    dtype = np.uint8 if top == 255 else np.uint16
    frames = rng.integers(0, top + 1, (6, 24, 40)).astype(dtype)
    frames[0, 0, 0] = top
    source = "gray" if dtype == np.uint8 else "gray16le"
    if pix_fmt == "gray12le":
        source = "gray16le"  # PyAV takes 16-bit arrays; FFmpeg's converter maps them to 12 bits
        frames >>= 4
        frames <<= 4  # values a 16 -> 12 bit conversion keeps: its 12-bit codes are frames >> 4
    path = _pyav_video(tmp_path / name, frames, codec, pix_fmt, source)
    with open_frames(path) as reader:
        bits = {"gray16le": 16, "gray12le": 12, "gray": 8}[pix_fmt]
        assert (reader.dtype, reader.bits, reader.lossy) == (np.dtype(dtype), bits, None)
        got = np.stack(list(reader.frames()))
    want = frames >> 4 if pix_fmt == "gray12le" else frames  # the 12-bit values as stored
    assert np.array_equal(got, want)


def test_an_unpadded_raw_avi_ffmpeg_writes_is_read_exactly(tmp_path):
    # FFmpeg writes raw grey as 'Y800', rows unpadded (13 bytes, not a DIB's 16): not a short frame
    frames = np.random.default_rng(9).integers(0, 256, (5, *SHAPE), dtype=np.uint8)
    path = _pyav_video(tmp_path / "y800.avi", frames, "rawvideo", "gray", "gray")
    with open_frames(path) as reader:
        assert reader.fourcc == "Y800" and reader.count == 5 and reader.lossy is None
        assert np.array_equal(np.stack(list(reader.frames())), frames)


@pytest.mark.parametrize(("codec", "shown"), [("mjpeg", "mjpeg"), ("libx264", "h264"), ("mpeg4", "mpeg4")])
def test_lossy_videos_name_their_codec(tmp_path, codec, shown):
    grey = np.random.default_rng(8).integers(0, 256, (6, 32, 48), dtype=np.uint8)
    frames = np.repeat(grey[..., None], 3, axis=3)
    pix_fmt = "yuvj420p" if codec == "mjpeg" else "yuv420p"
    path = _pyav_video(tmp_path / f"{codec}.mp4", frames, codec, pix_fmt, "rgb24")
    with open_frames(path, "luma") as reader:  # lossy chroma need not stay exactly neutral: colour
        assert reader.lossy == shown and f"'{shown}' is lossy" in reader.notes[0]
        got = np.stack(list(reader.frames()))
    assert got.shape == grey.shape and got.dtype == np.uint8
    assert np.abs(got.astype(int) - grey).mean() < 40  # lossy, but the picture


def test_hostile_avis_are_refused_naming_the_file(tmp_path):
    for case, path in hostile_avis(tmp_path).items():
        with pytest.raises(ReaderError, match=rf"^{path}: ") as raised, open_frames(path) as reader:
            for _ in reader.frames():
                pass
        message = str(raised.value)
        assert "\n" not in message, case
        if case == "2^31 frames":
            assert "announces 2,147,483,648 frames" in message
        if case == "45000x4":
            assert "too few for the 3 frames of 45000x4 pixels its header announces" in message
        if case == "45000x4, no count":  # each frame's chunk is checked against the header's frame size
            assert "frame 0 holds 112 bytes where the header's frames of 45000x4 pixels need 180,000" in message
        if case.startswith("cut"):
            assert "too few for the 40 frames of 64x48 pixels its header announces" in message, message


def test_a_missing_video_is_missing(tmp_path):
    from edgedsm.frameio import InputMissing
    from edgedsm.frameio.video import VideoReader

    with pytest.raises(InputMissing, match=r"gone\.avi: no such file"):
        VideoReader(tmp_path / "gone.avi")
