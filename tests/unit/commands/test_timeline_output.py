"""analyze --timeline's figures say what they show: a short title (the input's file name; the whole
path in the PNG's Source text), τc's ticks in seconds with an SI prefix instead of "6.675×10⁻¹"."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from edgedsm.cli import main
from edgedsm.commands.timeline_output import activity_figure, figure_title
from edgedsm.timeline import timeline


def test_the_title_is_the_file_name_not_its_folders() -> None:
    long = "/srv/plant/recordings/2026-12-05/line-3/camera-left/run-0042.npy"
    assert figure_title(long, 64, 2) == "run-0042.npy: N = 64, m = 2"
    assert figure_title("default", 200, 10) == "default: N = 200, m = 10"  # a scene keeps its name


def _result():
    frames = np.random.default_rng(4).integers(0, 256, (48, 16, 16), dtype=np.uint8)
    return timeline(iter(frames), {"frame": np.ones((16, 16), bool)}, 24, 2, 8, dt=0.05, max_lag=12)


def test_tau_c_ticks_are_seconds_with_a_prefix_on_a_narrow_and_a_wide_range() -> None:
    fig = activity_figure(_result(), "run.npy: N = 24, m = 2")
    try:
        assert fig._suptitle.get_text() == "Activity against time — run.npy: N = 24, m = 2"
        tau = fig.axes[-1]
        seconds = re.compile(r"^-?\d+(\.\d+)? (ns|µs|ms|s)$")
        for low, high in ((0.62, 0.71), (1e-3, 30.0)):  # minor ticks labelled / decades only
            tau.set_ylim(low, high)
            fig.canvas.draw()
            labels = [tick.get_text() for tick in (*tau.get_yticklabels(), *tau.get_yticklabels(minor=True))
                      if tick.get_text()]
            assert labels, (low, high)
            assert all(seconds.match(text) for text in labels), labels
        assert {"1 ms", "10 ms", "100 ms", "1 s", "10 s"} <= set(labels)
    finally:
        from matplotlib import pyplot

        pyplot.close(fig)


def test_the_saved_figures_carry_the_whole_path_in_their_source_text(tmp_path: Path) -> None:
    deep = tmp_path / "a folder name long enough to be cut off" / "another one" / "run.npy"
    deep.parent.mkdir(parents=True)
    np.save(deep, np.random.default_rng(5).integers(0, 256, (40, 16, 16), dtype=np.uint8))
    out = tmp_path / "out"
    assert main(["analyze", str(deep), "--timeline", str(out), "--window", "20", "--lag", "2", "--max-lag", "8",
                 "--every", "10", "--no-progress"]) == 0
    for name in ("timeline.png", "histogram.png"):
        data = (out / name).read_bytes()
        assert b"tEXtSource\x00" + str(deep).encode() in data, name
