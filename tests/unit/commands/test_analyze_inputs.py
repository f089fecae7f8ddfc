"""`edgedsm analyze` on what labs record (videos, colour image series, TIFF), through the CLI:
maps equal to the frames' maps, bad input as one line with exit 65/66, --timeline streamed."""

from __future__ import annotations

import tracemalloc

import cv2
import numpy as np
import pytest
import tifffile

from edgedsm.cli import main
from edgedsm.estimators import s1, s2


def _speckle(count, shape=(24, 32), colour=False, seed=0):
    size = (count, *shape, 3) if colour else (count, *shape)
    return np.random.default_rng(seed).integers(0, 256, size, dtype=np.uint8)


def _video(path, frames, fourcc):
    colour = frames.ndim == 4
    writer = cv2.VideoWriter(str(path), cv2.CAP_FFMPEG, cv2.VideoWriter.fourcc(*fourcc), 10.0,
                             (frames.shape[2], frames.shape[1]), isColor=colour)
    for frame in frames:
        writer.write(frame)
    writer.release()
    return path


def _one_clear_line(err):
    lines = err.strip().splitlines()
    return len(lines) == 1 and "Traceback" not in err


def test_analyze_a_lossless_video_and_a_lossy_one_with_a_warning(tmp_path, capsys):
    frames = _speckle(10)
    out = tmp_path / "m.npy"
    assert main(["analyze", str(_video(tmp_path / "v.avi", frames, "FFV1")), "--lag", "2", "--start", "1",
                 "--window", "8", "-o", str(out)]) == 0
    assert np.array_equal(np.load(out), s1(frames[1:9], 2))
    assert main(["analyze", str(_video(tmp_path / "j.avi", frames, "MJPG")), "--lag", "2", "-o", str(out)]) == 0
    assert "codec 'MJPG' is lossy" in capsys.readouterr().err


def test_analyze_a_colour_bmp_series_by_channel(tmp_path, capsys):
    bgr = _speckle(12, colour=True, seed=2)
    folder = tmp_path / "drying"
    folder.mkdir()
    for index, image in enumerate(bgr, start=1):
        cv2.imwrite(str(folder / f"img_{index}.bmp"), image)
    out = tmp_path / "red.npy"
    assert main(["analyze", str(folder), "--channel", "red", "--estimator", "s2", "--lag", "3",
                 "-o", str(out)]) == 0
    assert np.array_equal(np.load(out), s2(bgr[..., 2], 3))  # natural order img_1 .. img_12, red = index 2
    capsys.readouterr()
    assert main(["analyze", str(folder), "--lag", "3", "-o", str(out)]) == 65
    err = capsys.readouterr().err
    assert _one_clear_line(err) and "drying is colour" in err and "--channel" in err
    assert main(["analyze", str(folder), "--channel", "infrared", "--lag", "3", "-o", str(out)]) == 65
    err = capsys.readouterr().err
    assert _one_clear_line(err) and "unknown channel 'infrared'" in err and "drying" in err


def _bad_inputs(tmp_path):
    """(path, text the message must hold, exit code) for each kind of bad input."""
    cases = []
    full = tmp_path / "full.tif"
    tifffile.imwrite(full, _speckle(10, (64, 64)), compression="zlib")
    (tmp_path / "cut.tif").write_bytes(full.read_bytes()[: full.stat().st_size // 2])
    cases.append((tmp_path / "cut.tif", "cut.tif", 65))
    video = _video(tmp_path / "full.avi", _speckle(30, (48, 64)), "FFV1")
    (tmp_path / "cut.avi").write_bytes(video.read_bytes()[: video.stat().st_size // 2])
    cases.append((tmp_path / "cut.avi", "cut.avi: ends after", 65))
    odd = tmp_path / "odd"
    odd.mkdir()
    for index in range(6):
        cv2.imwrite(str(odd / f"{index}.png"), np.zeros((16, 20 if index == 4 else 16), np.uint8))
    cases.append((odd, "4.png: 16x20 frame among 16x16", 65))
    index = tmp_path / "index.tif"
    with tifffile.TiffWriter(index, bigtiff=True) as writer:
        writer.write(np.zeros((8, 8), np.uint8), description='{"edgedsm_recording":1,"seq":0,"t_ns":0,"laser":"on"}',
                     metadata=None)
        writer.write(np.zeros((8, 8), np.uint8), description='{"seq":1,"t_ns":"late"}', metadata=None)
        writer.write(np.zeros((8, 8), np.uint8), description='{"seq":2,"t_ns":2,"laser":"on"}', metadata=None)
    cases.append((index, "index.tif page 1: the recording index is corrupt", 65))
    cases.append((tmp_path / "nothing.avi", "nothing.avi: no such file", 66))
    return cases


@pytest.mark.parametrize("timeline", [False, True])
def test_bad_input_is_one_clear_line_and_exit_65_or_66(tmp_path, capsys, timeline):
    for path, said, code in _bad_inputs(tmp_path):
        capsys.readouterr()
        # the map reads all frames (no --window): a truncated tail is met, as the timeline meets it
        output = (["--timeline", str(tmp_path / "tl"), "--window", "6", "--max-lag", "2"] if timeline
                  else ["-o", str(tmp_path / "m.npy")])
        assert main(["analyze", str(path), "--lag", "1", *output]) == code, path
        err = capsys.readouterr().err
        assert _one_clear_line(err) and said in err, err
        assert not (tmp_path / "m.npy").exists() and not (tmp_path / "tl" / "timeline.csv").exists()


def _timeline_peak(tmp_path, count, monkeypatch):
    """The most memory Python held while the timeline streamed the recording (tracemalloc), up to
    the CSV: the figures drawn after it take the same memory whatever the length, and how much of
    matplotlib's canvases the collector has freed by then depends on the tests run before."""
    from edgedsm.commands import timeline_output

    streamed: list[int] = []
    write_csv = timeline_output.write_csv

    def measured(*args, **kwargs):
        streamed.append(tracemalloc.get_traced_memory()[1])
        return write_csv(*args, **kwargs)

    monkeypatch.setattr(timeline_output, "write_csv", measured)
    path = tmp_path / f"long{count}.tif"
    rng = np.random.default_rng(0)
    with tifffile.TiffWriter(path, bigtiff=True) as writer:
        for _ in range(count):
            writer.write(rng.integers(0, 4096, (96, 96), dtype=np.uint16), contiguous=False)
    tracemalloc.start()
    try:
        assert main(["analyze", str(path), "--timeline", str(tmp_path / f"tl{count}"), "--window", "10",
                     "--lag", "2", "--every", "40", "--max-lag", "4", "--no-progress"]) == 0
        return streamed[-1]
    finally:
        tracemalloc.stop()


@pytest.mark.slow
def test_timeline_memory_does_not_grow_with_the_recording(tmp_path, capsys, monkeypatch):
    _timeline_peak(tmp_path, 20, monkeypatch)  # kernels compiled and plotting loaded before measuring
    short, long = _timeline_peak(tmp_path, 60, monkeypatch), _timeline_peak(tmp_path, 300, monkeypatch)
    frame_bytes = 96 * 96 * 2
    # 240 more frames would add 4.4 MB if they were held; streamed, the peak stays put
    assert long - short < 40 * frame_bytes, (short, long)
    out = capsys.readouterr().out
    assert "from 300 frames" in out


def test_timeline_of_a_recording_keeps_its_clock(tmp_path, capsys):
    from edgedsm.frameio.recording import RecordingWriter
    from edgedsm.frames import Frame

    rng = np.random.default_rng(4)
    t_ns = [i * 100_000_000 + (300_000_000 if i >= 12 else 0) for i in range(24)]  # 3 frames lost after 11
    path = tmp_path / "rec.tif"
    with RecordingWriter(path) as writer:
        for seq, t in enumerate(t_ns):
            writer.write(Frame(rng.integers(0, 256, (16, 16), dtype=np.uint8), seq, 10**9 + t, 8))
    out = tmp_path / "tl"
    assert main(["analyze", str(path), "--timeline", str(out), "--window", "6", "--lag", "1", "--every", "6",
                 "--max-lag", "3", "--start", "2", "--no-progress"]) == 0
    rows = (out / "timeline.csv").read_text().splitlines()[1:]
    frames = [int(row.split(",")[0]) for row in rows]
    times = [float(row.split(",")[1]) for row in rows]
    # frame k of the timeline is frame k + 2 of the file; the clock jumps by 0.3 s after file frame 11
    assert frames == [5, 11, 17] and times == pytest.approx([0.5, 1.4, 2.0])
    assert "Δt = 0.1 s" in capsys.readouterr().out  # the median interval
