"""edgedsm recordings: every codec lossless at 8 and 16 bits, stamps kept per page, readable
after the recorder is killed with SIGKILL, a corrupt index named, never overwritten."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import tifffile

from edgedsm.errors import DataError
from edgedsm.frameio import ReaderError, open_frames
from edgedsm.frameio.recording import CODECS, OutputExists, RecordingWriter, page_description
from edgedsm.frames import Frame


def _frames(count, dtype, bits, shape=(24, 40)):
    rng = np.random.default_rng(5)
    return [Frame(rng.integers(0, 2**bits, shape, dtype=dtype), 100 + 2 * i, 10**12 + i * 25_000_000, bits)
            for i in range(count)]


@pytest.mark.parametrize("codec", list(CODECS))
@pytest.mark.parametrize(("dtype", "bits"), [(np.uint8, 8), (np.uint16, 12), (np.uint16, 16)])
def test_every_codec_reads_back_bit_identically_with_its_stamps(tmp_path, codec, dtype, bits):
    frames = _frames(6, dtype, bits)
    path = tmp_path / "rec.tif"
    with RecordingWriter(path, codec=codec, source="sim:default", header={"exposure_us": 500.0}) as writer:
        for index, frame in enumerate(frames):
            writer.write(frame, "on" if index else "off")
    with open_frames(path) as reader:
        assert (reader.kind, reader.count, reader.dtype, reader.bits) == ("recording", 6, dtype, bits)
        assert all(np.array_equal(a, b.pixels) for a, b in zip(reader.frames(), frames, strict=True))
        stamps = reader.stamps()
        assert stamps.seq.tolist() == [f.seq for f in frames]
        assert stamps.t_ns.tolist() == [f.t_ns for f in frames]
        assert stamps.laser == ("off", "on", "on", "on", "on", "on")
        assert reader.dt == pytest.approx(0.025)
        assert reader.header["source"] == "sim:default" and reader.header["exposure_us"] == 500.0
    with tifffile.TiffFile(path) as tif:  # a BigTIFF any TIFF tool opens
        assert tif.is_bigtiff and len(tif.pages) == 6


_CHILD = """
import sys, numpy as np
from edgedsm.frameio.recording import RecordingWriter
from edgedsm.frames import Frame
with RecordingWriter(sys.argv[1]) as writer:
    seq = 0
    while True:
        pixels = np.random.default_rng(seq).integers(0, 65536, (256, 256), dtype=np.uint16)
        writer.write(Frame(pixels, seq, seq * 1000, 16), "on")
        seq += 1
"""


@pytest.mark.parametrize("delay", [0.0, 0.013, 0.029])
def test_a_recording_killed_with_sigkill_keeps_every_complete_frame(tmp_path, delay):
    path = tmp_path / "killed.tif"
    child = subprocess.Popen([sys.executable, "-c", _CHILD, str(path)])
    try:
        deadline = time.monotonic() + 60
        # 42 frames of bytes: at least 40 complete pages whatever the page overhead and the partial last one
        while (not path.exists() or path.stat().st_size < 42 * 131_072) and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(delay)  # a different moment of the write cycle each time
    finally:
        child.send_signal(signal.SIGKILL)
        child.wait()
    size = path.stat().st_size
    with open_frames(path) as reader:
        count = reader.count
        for seq, pixels in enumerate(reader.frames()):
            expected = np.random.default_rng(seq).integers(0, 65536, (256, 256), dtype=np.uint16)
            assert np.array_equal(pixels, expected), seq
        assert reader.stamps().seq.tolist() == list(range(count))
    assert count >= 40 and count * 131_072 <= size < (count + 2) * 131_072 + 4096


def test_a_corrupt_index_is_named(tmp_path):
    path = tmp_path / "bad.tif"
    frame = np.zeros((4, 4), np.uint8)
    with tifffile.TiffWriter(path, bigtiff=True) as writer:
        writer.write(frame, description=page_description(0, 0, "on", {"bits": 8}), metadata=None)
        writer.write(frame, description=json.dumps({"seq": "one"}), metadata=None)
        writer.write(frame, description=page_description(2, 2, "on"), metadata=None)
    with pytest.raises(ReaderError, match=r"bad\.tif page 1: the recording index is corrupt"):
        open_frames(path)
    last = tmp_path / "last.tif"  # a complete last page with a bad record is corrupt too, not "incomplete"
    with tifffile.TiffWriter(last, bigtiff=True) as writer:
        writer.write(frame, description=page_description(0, 0, "on", {"bits": 8}), metadata=None)
        writer.write(frame, description="{}", metadata=None)
    with pytest.raises(ReaderError, match=r"last\.tif page 1: the recording index is corrupt"):
        open_frames(last)


def test_recordings_are_never_overwritten_and_empty_ones_are_removed(tmp_path):
    path = tmp_path / "rec.tif"
    path.write_bytes(b"precious")
    with pytest.raises(OutputExists, match="never overwritten"):
        RecordingWriter(path)
    assert path.read_bytes() == b"precious"
    empty = tmp_path / "empty.tif"
    RecordingWriter(empty).close()
    assert not empty.exists()
    with pytest.raises(DataError, match="unknown recording codec"):
        RecordingWriter(tmp_path / "x.tif", codec="jpeg")


def test_frames_that_change_size_or_type_are_refused(tmp_path):
    with RecordingWriter(tmp_path / "r.tif") as writer:
        writer.write(Frame(np.zeros((4, 4), np.uint8), 0, 0, 8))
        with pytest.raises(DataError, match="4x5 uint8 after 4x4 uint8"):
            writer.write(Frame(np.zeros((4, 5), np.uint8), 1, 1, 8))
        with pytest.raises(DataError, match="2-D uint8 or uint16"):
            writer.write(Frame(np.zeros((4, 4), np.float32), 2, 2, 8))
