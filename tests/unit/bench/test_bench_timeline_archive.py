"""`edgedsm bench recording --timeline`: each part's peak RSS is its own process's, and a quick
series gives the table and the two figures."""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from edgedsm.frameio import open_frames
from edgedsm_lab.bench import timeline_archive
from edgedsm_lab.bench.timeline_archive import GIB, make_series, measure


def test_a_parts_peak_is_the_childs_own() -> None:
    megabytes = 300
    touch = f"b = bytearray({megabytes} << 20); b[::4096] = b'x' * len(b[::4096])"  # every page written
    grow = measure("grow", [sys.executable, "-c", touch], timeout=60)
    small = measure("small", [sys.executable, "-c", "pass"], timeout=60)
    assert grow.peak >= megabytes * 2**20 > small.peak
    assert grow.peak < small.peak + (megabytes + 64) * 2**20
    assert grow.seconds > 0


def test_a_failing_part_says_why() -> None:
    with pytest.raises(RuntimeError, match="exit 3"):
        measure("fails", [sys.executable, "-c", "import sys; sys.exit(3)"], timeout=60)


def test_the_series_is_speckle_of_the_asked_size(tmp_path: Path) -> None:
    make_series(tmp_path, 30, 24, 40)
    with open_frames(tmp_path) as reader:
        frames = np.stack(list(reader.frames()))
    assert frames.shape == (30, 24, 40) and frames.dtype == np.uint8
    assert 50 < frames.mean() < 70  # |E|²·30, E complex Gaussian of unit variance per component
    lag1 = np.corrcoef(frames[:-1].ravel(), frames[1:].ravel())[0, 1]
    assert lag1 == pytest.approx(np.exp(-1 / 10), abs=0.05)  # τc = 10 frames in intensity


def test_the_quick_run_prints_both_figures(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "timeline.md"
    args = argparse.Namespace(quick=True, timeline_dir=str(tmp_path / "series"), timeline_timeout=300.0,
                              timeline_rounds=1, output=str(out))
    assert timeline_archive.run(args) == 0
    text = out.read_text()
    names = "decoding alone|decoding \\+ the bare engine|analyze --timeline"
    rows = dict(re.findall(rf"^\| ({names}) \| [\d.]+ \| ([\d.]+) \|", text, re.M))  # name, mean s
    assert len(rows) == 3 and all(float(seconds) > 0 for seconds in rows.values())
    pushing = re.search(r"^\| \(the bare engine alone[^|]*\| [\d.]+ \| ([\d.]+) \|", text, re.M).group(1)
    assert 0 < float(pushing) < float(rows["decoding + the bare engine"])
    peak, ratio = re.search(r"peak RSS ([\d.]+) GiB \(bound 1.5\), ([\d.]+)× decoding", text).groups()
    assert 0.05 < float(peak) < timeline_archive.PEAK_GIB
    # the seconds are printed to 0.1 s, the ratio from the unrounded ones
    assert float(ratio) == pytest.approx(float(rows["analyze --timeline"]) / float(rows["decoding + the bare engine"]),
                                         rel=0.2)
    assert float(ratio) > 1  # the timeline does what the bare engine does, and more
    assert "120 frames of 512x256" in capsys.readouterr().out
    assert GIB == 2**30
