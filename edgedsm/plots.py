"""What every figure edgedsm saves shares: matplotlib without a screen, and times on an axis in
seconds with an SI prefix ("667.5 ms", not "6.675×10⁻¹"), written once for ``analyze
--timeline``'s τc axis and ``tune``'s cost axis alike."""

from __future__ import annotations

import math
from typing import Any

#: SI prefixes of engineering notation (powers of 1000) the tick labels use.
_PREFIXES = {-9: "n", -6: "µ", -3: "m", 0: ""}


def pyplot() -> Any:
    """matplotlib's pyplot on the Agg backend (no display needed), imported on first use."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    return plt


def seconds_label(value: float) -> str:
    """A time as a tick reads it, in engineering notation with its unit: 0.6675 -> "667.5 ms",
    2 -> "2 s", 1.5e-5 -> "15 µs", 1500 -> "1500 s" (at most 4 significant digits; 0 -> "0 s")."""
    if value == 0 or not math.isfinite(value):
        return f"{value:g} s"
    exponent = min(max(3 * math.floor(math.log10(abs(value)) / 3), -9), 0)
    scaled = float(f"{value / 10.0 ** exponent:.4g}")
    if abs(scaled) >= 1000 and exponent < 0:  # 999.96 ms rounds to 1000: write 1 s
        exponent, scaled = exponent + 3, float(f"{scaled / 1000:.4g}")
    return f"{scaled:g} {_PREFIXES[exponent]}s"


def seconds_axis(axis: Any) -> None:
    """Label a logarithmic matplotlib ``axis`` (``ax.xaxis`` or ``ax.yaxis``) holding seconds with
    :func:`seconds_label`, at the ticks matplotlib's log formatter would label (so minor ticks do
    not crowd)."""
    from matplotlib.ticker import Formatter, LogFormatterSciNotation

    class SecondsFormatter(Formatter):
        def __init__(self, minor: bool) -> None:
            self.chooser = LogFormatterSciNotation(labelOnlyBase=not minor)

        def set_axis(self, axis: Any) -> None:
            super().set_axis(axis)
            self.chooser.set_axis(axis)

        def set_locs(self, locs: Any) -> None:
            super().set_locs(locs)
            self.chooser.set_locs(locs)

        def __call__(self, x: float, pos: int | None = None) -> str:
            return seconds_label(x) if self.chooser(x, pos) else ""

    axis.set_major_formatter(SecondsFormatter(minor=False))
    axis.set_minor_formatter(SecondsFormatter(minor=True))
