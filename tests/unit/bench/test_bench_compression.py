"""`edgedsm bench compression`: a tiny run through the command, its tables, and numbers that could fail."""

from __future__ import annotations

import argparse
import itertools
import re

import numpy as np
import pytest

from edgedsm.cli import main
from edgedsm.commands import bench
from edgedsm.sim import Simulator
from edgedsm_lab.bench.compression import lossless_rows
from edgedsm_lab.bench.compression_cost import (
    DEPTHS,
    ESTIMATORS,
    Plan,
    depth_stats,
    lossless_codecs,
    scene_at,
)

TINY = ["--size", "32", "--frames", "40", "--speed-frames", "2", "--repeats", "1", "--lag", "2", "--max-lag", "8"]


def test_scene_at_changes_only_the_bit_depth() -> None:
    for bits, dtype in ((8, np.uint8), (12, np.uint16), (16, np.uint16)):
        scene = scene_at(bits, 32)
        frame = Simulator(scene).next_frame()
        assert scene.detector is not None and scene.detector.bits == bits
        assert frame.dtype == dtype and frame.max() <= 2**bits - 1
        assert [r.tau_c for r in scene.activity.regions] == [10.0, 10.0] and scene.activity.tau_c == 50.0


def test_depth_stats_of_known_frames() -> None:
    frames = np.array([[0, 1], [2, 3]], np.uint16)  # four equally likely levels: 2 bits/pixel
    stats = depth_stats(frames, 12)
    assert (stats.levels, stats.itemsize, stats.entropy) == (4, 2, pytest.approx(2.0))
    assert stats.entropy_ratio == pytest.approx(8.0)


def test_every_lossless_codec_round_trips_every_depth() -> None:
    rng = np.random.default_rng(0)
    absent: list[str] = []
    codecs = lossless_codecs(absent)
    assert {"zstd", "zlib", "lzw", "png"} & set(absent) == set()  # the ones the issue names must be there
    for bits in DEPTHS:
        frame = rng.integers(0, 2**bits, (24, 40)).astype(np.uint8 if bits == 8 else np.uint16)
        for codec in codecs:
            if bits in codec.depths:
                back = codec.decode(codec.encode(frame, bits), frame)
                assert back.dtype == frame.dtype and np.array_equal(back, frame), (codec.label, bits)


def test_bad_sizes_are_one_line(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "compression", *TINY[:2], "--frames", "5", "--max-lag", "8"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "frames (5) must exceed" in err[0]
    with pytest.raises(ValueError):
        Plan(size=8)


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory: pytest.TempPathFactory):
    from edgedsm_lab.bench import compression

    output = tmp_path_factory.mktemp("compression") / "compression.md"
    parser = argparse.ArgumentParser()
    bench.add_arguments(parser)
    args = parser.parse_args(["compression", *TINY, "--output", str(output)])
    captured: list = []
    measure = compression.measure

    def keep(*a, **k):
        captured.append(measure(*a, **k))
        return captured[-1]

    with pytest.MonkeyPatch.context() as patch:  # the command's own run; its results kept to check numbers
        patch.setattr(compression, "measure", keep)
        assert bench.run(args) == 0
    return captured[0], output.read_text()


@pytest.mark.slow
def test_tiny_run_writes_every_table(tiny_run) -> None:
    results, text = tiny_run
    codecs = lossless_codecs([])
    for heading in ("## What the frames hold", "### 8 bits", "### 12 bits", "### 16 bits",
                    "## Lossy codecs and what the maps lose", "## Conclusions"):
        assert heading in text
    for bits in DEPTHS:
        rows = lossless_rows(results, bits)
        assert len(rows) == sum(bits in c.depths for c in codecs) and all(len(row) == 10 for row in rows)
        for row in rows:  # every row is in the file as written
            assert "| " + " | ".join(row) + " |" in text
    lossy_part = text[text.index("## Lossy codecs"): text.index("## Conclusions")]
    lossy_lines = [line for line in lossy_part.splitlines() if re.match(r"\| (JPEG|WebP|zstd \(lossless)", line)]
    assert len(lossy_lines) == 2 * len(results.lossy)  # once in the cost table, once in the β / AUC table
    assert "Every lossless codec gave back every pixel." in text


@pytest.mark.slow
def test_tiny_run_numbers(tiny_run) -> None:
    results, _ = tiny_run
    assert [d.bits for d in results.depths] == list(DEPTHS)
    for row in results.lossless:
        assert row.identical, row.codec.label
        assert 0.5 < row.ratio < 3 * results.depths[DEPTHS.index(row.bits)].entropy_ratio
        assert row.speed.encode_mb_s > 0 and row.speed.decode_mb_s > 0
        if row.codec.tiff is None:
            assert row.tiff is None
        else:  # every TIFF mode listed is one tifffile writes and reads back
            assert row.tiff is not None and row.tiff.tifffile == "yes", (row.codec.label, row.bits, row.tiff)
        if row.codec.name == "deflate (zlib)":  # Adobe deflate is baseline for every TIFF reader
            assert row.tiff is not None and row.tiff.opencv and row.tiff.pillow, row.bits
    control, *lossy = results.lossy
    assert control.codec.lossless and control.frame_rms == 0.0
    assert all(control.quality.error[n] == 0.0 for n in ESTIMATORS)
    assert control.quality.auc == results.reference.auc and control.quality.beta == results.reference.beta
    by_codec: dict[str, list] = {}
    for row in lossy:
        by_codec.setdefault(row.codec.name, []).append(row)
    assert {"JPEG (libjpeg-turbo)", "JPEG 2000 (OpenJPEG)"} <= set(by_codec)
    for name, rows in by_codec.items():  # best setting first: more loss and a higher ratio down the list
        rms = [row.frame_rms for row in rows]
        assert rms[0] > 0 and all(a < b for a, b in itertools.pairwise(rms)), (name, rms)
        ratios = [row.ratio for row in rows]
        assert all(a < b for a, b in itertools.pairwise(ratios)), (name, ratios)
        for estimator in ("s1", "s2", "s3"):
            assert 0 < rows[0].quality.error[estimator] < rows[-1].quality.error[estimator], (name, estimator)
