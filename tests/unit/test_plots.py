"""Times on a figure's axis read in seconds with an SI prefix, on every figure that shows them
(analyze --timeline's τc, tune's cost per frame)."""

from __future__ import annotations

import re

import pytest

from edgedsm.plots import pyplot, seconds_axis, seconds_label

SECONDS = re.compile(r"^-?\d+(\.\d+)? (ns|µs|ms|s)$")


@pytest.mark.parametrize(("seconds", "label"), [
    (0.6675, "667.5 ms"), (2.0, "2 s"), (1.5e-5, "15 µs"), (0.99996, "1 s"), (0.0009999, "999.9 µs"),
    (1234.5, "1234 s"), (0.05, "50 ms"), (3e-8, "30 ns"), (0.0, "0 s"),
])
def test_seconds_read_as_engineering_notation_with_their_unit(seconds: float, label: str) -> None:
    assert seconds_label(seconds) == label


@pytest.mark.parametrize(("low", "high", "expected"), [
    (2e-4, 3e-2, {"1 ms", "10 ms"}),  # a tune report's push costs: decades labelled
    (4e-3, 9e-3, {"5 ms", "6 ms"}),  # within a decade: the minor ticks labelled
])
def test_a_log_axis_of_seconds_labels_its_ticks_with_a_prefix(low: float, high: float, expected: set[str]) -> None:
    plt = pyplot()
    fig, ax = plt.subplots()
    try:
        ax.scatter([low, high], [1.0, 2.0])
        ax.set_xscale("log")
        seconds_axis(ax.xaxis)
        ax.set_xlim(low, high)
        fig.canvas.draw()
        labels = [tick.get_text() for tick in (*ax.get_xticklabels(), *ax.get_xticklabels(minor=True))
                  if tick.get_text()]
        assert labels and all(SECONDS.match(text) for text in labels), labels
        assert expected <= set(labels), labels
    finally:
        plt.close(fig)
