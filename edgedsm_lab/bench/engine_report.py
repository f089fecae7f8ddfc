"""The report side of ``edgedsm bench engine``: its result rows, markdown tables and figure."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from edgedsm.plots import pyplot
from edgedsm_lab.bench.report import markdown_table

MODES = ("sliding", "tumbling", "exponential")


@dataclass
class Row:
    """One (size, mode, kernel) measurement."""

    size: tuple[int, int]
    mode: str
    kernel: str
    ms: float  # best push
    median_ms: float
    maps_ms: float
    state_bytes: float
    traffic_bytes: float
    bound_ms: float
    batch_ms: float
    errors: dict[str, float] | None  # max |map - batch| per map; None: not measured
    note: str = ""

    @property
    def pixels(self) -> int:
        return self.size[0] * self.size[1]


def fmt_errors(errors: dict[str, float] | None) -> str:
    if errors is None:
        return "as the first kernel"
    return " / ".join("0" if value == 0 else f"{value:.1e}" for value in errors.values())


def speed_table(rows: list[Row]) -> list[str]:
    header = ["frame", "mode", "kernel", "ms/frame best (median)", "Mpx/s", "state B/px", "moved B/px",
              "x bandwidth bound", "maps() ms", "speed-up vs batch: push / push+maps",
              "max abs error S1 / S2 / S3", "note"]
    return markdown_table(header, [
        [f"{row.size[1]}x{row.size[0]}", row.mode, row.kernel, f"{row.ms:.2f} ({row.median_ms:.2f})",
         f"{row.pixels / row.ms / 1e3:.0f}", f"{row.state_bytes:.0f}", f"{row.traffic_bytes:.0f}",
         f"{row.ms / row.bound_ms:.2f}", f"{row.maps_ms:.1f}",
         f"{row.batch_ms / row.ms:.0f}x / {row.batch_ms / (row.ms + row.maps_ms):.0f}x",
         fmt_errors(row.errors), row.note] for row in rows], align="lll" + "r" * 7 + "ll")


def noise_table(noise: list[dict[str, Any]]) -> list[str]:
    header = ["N", "sliding S1", "sliding S2", "sliding S3", "exponential S1", "exponential S2",
              "exponential S3", "mean S1 / S2 / S3 (sliding)"]
    rows = []
    for row in noise:
        cells = [f"{100 * row[(mode, name)]:.1f} %" for mode in ("sliding", "exponential")
                 for name in ("s1", "s2", "s3")]
        means = " / ".join(f"{row[('sliding', name, 'mean')]:.3g}" for name in ("s1", "s2", "s3"))
        rows.append([row["N"], *cells, means])
    return markdown_table(header, rows, align="r" * 7 + "l")


def plot(rows: list[Row], noise: list[dict[str, Any]], path: Path) -> bool:
    """Two panels: ms/frame per mode and kernel; map spread against N. False without mpl."""
    try:
        import matplotlib.ticker

        plt = pyplot()
    except ImportError:
        return False
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.5))
    labels = sorted({(r.mode, r.kernel, r.note == "1 thread") for r in rows},
                    key=lambda k: (MODES.index(k[0]), k[1], k[2]))
    sizes = sorted({r.size for r in rows}, key=lambda s: s[0] * s[1])
    width = 0.8 / max(1, len(labels))
    for k, (mode, kernel, single) in enumerate(labels):
        values, bounds = [], []
        for size in sizes:
            match = [r for r in rows if r.size == size and r.mode == mode and
                     r.kernel == kernel and (r.note == "1 thread") == single]
            values.append(match[0].ms if match else np.nan)
            bounds.append(match[0].bound_ms if match else np.nan)
        x = np.arange(len(sizes)) + k * width
        left.bar(x, values, width, label=f"{mode} / {kernel}{' (1 thread)' if single else ''}")
        # each bar's own memory-bandwidth bound as a black tick across it
        left.hlines(bounds, x - width / 2, x + width / 2, colors="black", linewidth=2,
                    label="bandwidth bound" if k == 0 else None)
    left.set_xticks(np.arange(len(sizes)) + width * (len(labels) - 1) / 2,
                    [f"{s[1]}x{s[0]}" for s in sizes])
    left.set_yscale("log")
    left.set_ylabel("ms per frame (all three maps)")
    left.set_title("streaming engine, N = 200, m = 10")
    left.legend(fontsize=7, ncol=2)
    if noise:
        windows = [row["N"] for row in noise]
        for name, colour in (("s1", "C0"), ("s2", "C1"), ("s3", "C2")):
            for mode, style in (("sliding", "-o"), ("exponential", "--s")):
                right.plot(windows, [100 * row[(mode, name)] for row in noise], style,
                           color=colour, label=f"{name.upper()} {mode}")
        right.set_xscale("log")
        right.set_yscale("log")
        right.set_xticks(windows, [str(n) for n in windows])
        right.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        right.yaxis.set_minor_formatter(matplotlib.ticker.ScalarFormatter())
        right.yaxis.set_major_formatter(matplotlib.ticker.ScalarFormatter())
        right.set_xlabel("window N (frames)")
        right.set_ylabel("spatial spread std/mean (%)")
        right.set_title("map noise at constant activity (τc = 20 frames)")
        right.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return True
