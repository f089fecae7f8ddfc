"""TIFF and BigTIFF written by tifffile (compressed and not) and by OpenCV, read page by page;
damaged files named; a large file is streamed, not loaded."""

from __future__ import annotations

import tracemalloc

import cv2
import numpy as np
import pytest
import tifffile

from edgedsm.frameio import ReaderError, open_frames


def _stack(count=9, shape=(24, 32), top=4096, seed=0):
    return np.random.default_rng(seed).integers(0, top, (count, *shape), dtype=np.uint16 if top > 256 else np.uint8)


@pytest.mark.parametrize("compression", [None, "zlib", "zstd", "lzw"])
def test_bigtiff_written_by_tifffile_reads_back_exactly(tmp_path, compression):
    frames = _stack()
    path = tmp_path / "stack.tif"
    tifffile.imwrite(path, frames, bigtiff=True, compression=compression)
    with open_frames(path) as reader:
        assert (reader.kind, reader.count, reader.shape, reader.dtype, reader.bits) == \
            ("tiff", 9, (24, 32), np.uint16, 16)
        assert np.array_equal(np.stack(list(reader.frames())), frames)
        assert np.array_equal(reader.window(4, 3), frames[4:7])
        assert reader.stamps() is None and not reader.notes


def test_pages_written_one_by_one_and_by_opencv(tmp_path):
    frames = _stack(top=256)
    path = tmp_path / "pages.tif"
    with tifffile.TiffWriter(path) as writer:
        for frame in frames:
            writer.write(frame, compression="zlib", contiguous=False)
    opencv = tmp_path / "opencv.tif"
    assert cv2.imwritemulti(str(opencv), list(frames))
    for source in (path, opencv):
        with open_frames(source) as reader:
            assert np.array_equal(np.stack(list(reader.frames(2))), frames[2:]), source


def test_a_colour_tiff_needs_a_channel_in_rgb_order(tmp_path):
    rgb = np.random.default_rng(1).integers(0, 256, (3, 10, 12, 3), dtype=np.uint8)
    path = tmp_path / "colour.tif"
    tifffile.imwrite(path, rgb, photometric="rgb")
    with pytest.raises(ReaderError, match=r"colour.*--channel"):
        open_frames(path)
    with open_frames(path, "red") as reader:
        assert np.array_equal(np.stack(list(reader.frames())), rgb[..., 0])
    planar = tmp_path / "planar.tif"
    tifffile.imwrite(planar, np.moveaxis(rgb, -1, 1), photometric="rgb", planarconfig="separate")
    with open_frames(planar, "blue") as reader:
        assert np.array_equal(np.stack(list(reader.frames())), rgb[..., 2])


def test_a_lossy_tiff_is_noted_with_its_codec(tmp_path):
    path = tmp_path / "jpeg.tif"
    tifffile.imwrite(path, _stack(count=2, top=256), compression="jpeg")
    with open_frames(path) as reader:
        assert any("JPEG" in note and "lossy" in note for note in reader.notes) and reader.lossy == "JPEG"


@pytest.mark.parametrize(("compression", "fraction"), [(None, 0.5), ("zlib", 0.5), ("zlib", 0.97)])
def test_a_truncated_tiff_is_named(tmp_path, compression, fraction):
    path = tmp_path / "full.tif"
    tifffile.imwrite(path, _stack(count=10, shape=(64, 64), top=256), compression=compression)
    data = path.read_bytes()
    cut = tmp_path / "cut.tif"
    cut.write_bytes(data[: int(len(data) * fraction)])
    with pytest.raises(ReaderError, match=r"cut\.tif: .*(truncated|damaged)"), open_frames(cut) as reader:
        for _ in reader.frames():
            pass


def test_not_a_tiff_is_named(tmp_path):
    path = tmp_path / "fake.tif"
    path.write_bytes(b"II*\x00garbage" * 3)
    with pytest.raises(ReaderError, match=r"fake\.tif: cannot be read as a TIFF"):
        open_frames(path)


def test_reading_a_window_of_a_large_tiff_does_not_load_the_file(tmp_path):
    count, shape = 120, (256, 256)  # 15.7 MB of uint16 on disk
    path = tmp_path / "large.tif"
    with tifffile.TiffWriter(path, bigtiff=True) as writer:
        for index in range(count):
            writer.write(np.full(shape, index, np.uint16), contiguous=False)
    tracemalloc.start()
    try:
        with open_frames(path) as reader:
            window = reader.window(100, 10)
            for frame in reader.frames(110):
                assert frame.shape == shape
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert window[:, 0, 0].tolist() == list(range(100, 110))
    frame_bytes = shape[0] * shape[1] * 2
    assert peak < 20 * frame_bytes  # the window (10 frames) and a few pages, not the 120 frames
