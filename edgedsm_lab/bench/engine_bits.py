"""``edgedsm bench engine``'s "Each map alone" at 12 and 16 bits: S1, S2, S3 and S1+S2+S3 pushed
in turn, frame by frame, so a drift of the machine slows every map alike (issue 38: S2's
``float`` terms, docs/engine.md "S2's term").

Frames are exponential speckle with a mean of a quarter of full scale, clipped at full scale,
as uint16; q = 1 (Eq. 2's constant, grey levels), sliding window. Times in ms per push.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from edgedsm.estimators import SlidingWindow
from edgedsm_lab.bench.report import markdown_table

#: The paper's maps each alone, then together (what S2 costs against S1 at each bit depth).
SETS = (("s1",), ("s2",), ("s3",), ("s1", "s2", "s3"))
POOL = 16  # distinct frames cycled through the engines


def deep_pool(shape: tuple[int, int], bits: int, seed: int = 7) -> list[np.ndarray]:
    """Synthetic ``bits``-bit speckle frames (uint16): exponential intensities, mean full scale / 4."""
    rng = np.random.default_rng(seed)
    top = (1 << bits) - 1
    return [np.minimum(rng.exponential(top / 4.0, shape), top).astype(np.uint16) for _ in range(POOL)]


def needed_bytes(shape: tuple[int, int], window: int) -> int:
    """The four engines' rings (2 B per pixel per frame) and sums (at most 40 B per pixel)."""
    return len(SETS) * shape[0] * shape[1] * (2 * window + 40)


def bench_bits(shape: tuple[int, int], window: int, lag: int, bits: int, kernel: str, threads: int | None,
               log: Callable[[str], None], rounds: int | None = None) -> list[dict[str, Any]]:
    """Each set of SETS at ``bits``: best and median ms per push over ``rounds`` (default N) pushes
    in steady state, the engines taking turns push by push; the engine's S2 term kind."""
    pool = deep_pool(shape, bits)
    engines = [SlidingWindow(shape, window, lag, q=1.0, bits=bits, kernel=kernel, threads=threads, estimators=names)
               for names in SETS]
    for engine in engines:
        for j in range(window):  # fill: from here on every push adds and removes
            engine.push(pool[j % POOL])
    times: list[list[float]] = [[] for _ in engines]
    for j in range(window, window + (rounds or window)):
        for engine, spent in zip(engines, times, strict=True):
            start = time.perf_counter()
            engine.push(pool[j % POOL])
            spent.append(time.perf_counter() - start)
    rows = [{"shape": shape, "bits": bits, "estimators": "+".join(names), "kind": engine.ratio_kind,
             "ms": min(spent) * 1e3, "median_ms": statistics.median(spent) * 1e3}
            for names, engine, spent in zip(SETS, engines, times, strict=True)]
    log(f"  {bits}-bit " + ", ".join(f"{row['estimators']} {row['ms']:.2f}" for row in rows) + " ms/frame")
    return rows


def bits_table(rows: list[dict[str, Any]]) -> list[str]:
    """One line per (size, bit depth, set): best (median) ms per push and its ratio to S1's."""
    lines = []
    for row in rows:
        s1 = next(r for r in rows if r["shape"] == row["shape"] and r["bits"] == row["bits"]
                  and r["estimators"] == "s1")
        lines.append([f"{row['shape'][1]}x{row['shape'][0]}", row["bits"], row["estimators"],
                      row["kind"] if "s2" in row["estimators"] else "", f"{row['ms']:.3f} ({row['median_ms']:.3f})",
                      f"{row['ms'] / s1['ms']:.2f}"])
    return markdown_table(["frame", "bits", "estimators (sliding)", "S2 term", "ms/frame best (median)", "x S1"],
                          lines, "lrlrrr")
