"""`analyze --timeline` at the paper's series size, against decoding + pushing the same frames.

Issue 22's target: 600 frames of 4096×2168 (8-bit image folder), `--window 200 --lag 5 --every
200` (disjoint sets, the paper's Figs. 10-11), under 1.5 GiB peak RSS with τc on and within 2× of
decoding the frames and pushing them through the bare engine. Each part runs in its own process
under /usr/bin/time -v (peak RSS = its "Maximum resident set size"), one after the other, so the
ratios come from one run on one machine state:

    python scripts/timeline_paper_size.py --make /work/scratch/big600        # once: 600 PNG frames
    python scripts/timeline_paper_size.py /work/scratch/big600               # the table

Parts: decoding alone; decoding + pushing through the tumbling engine with S1-S3 (what the
timeline's engine keeps) and with S1-S3 + τc (K = --max-lag, the engine's own lag products);
``analyze --timeline`` with τc and with --no-tau-c. The frames of --make are a complex Gaussian
AR(1) field per pixel (τc = 10 frames in intensity), mean 60 grey levels, PNG level 1.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def make(folder: Path, count: int, height: int, width: int, tau: float = 10.0) -> None:
    import cv2
    import numpy as np

    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(1)
    r = np.float32(np.exp(-1 / (2 * tau)))  # field correlation: the intensity's is r² = exp(-1/τ)
    s = np.float32(np.sqrt(1 - r * r))
    real = rng.standard_normal((height, width), dtype=np.float32)
    imag = rng.standard_normal((height, width), dtype=np.float32)
    for index in range(count):
        real = r * real + s * rng.standard_normal((height, width), dtype=np.float32)
        imag = r * imag + s * rng.standard_normal((height, width), dtype=np.float32)
        frame = np.clip((real * real + imag * imag) * np.float32(30.0), 0, 255).astype(np.uint8)
        cv2.imwrite(str(folder / f"img_{index:04d}.png"), frame, [cv2.IMWRITE_PNG_COMPRESSION, 1])


def part(name: str, folder: str, window: int, lag: int, max_lag: int) -> None:
    """One measured part in this process (decode, push-s123, push-tau)."""
    from edgedsm.estimators import SlidingWindow
    from edgedsm.frameio import open_frames

    engine = None
    with open_frames(folder) as reader:
        for frame in reader.frames():
            if name == "decode":
                continue
            if engine is None:
                estimators = ("s1", "s2", "s3", "tau_c") if name == "push-tau" else ("s1", "s2", "s3")
                engine = SlidingWindow(frame.shape, window, lag, mode="tumbling", estimators=estimators,
                                       max_lag=max_lag if name == "push-tau" else None)
            engine.push(frame)


def measure(command: list[str]) -> tuple[float, float]:
    """(wall seconds, peak RSS GiB) of ``command`` under /usr/bin/time -v."""
    start = time.perf_counter()
    done = subprocess.run(["/usr/bin/time", "-v", *command], capture_output=True, text=True, check=True)
    wall = time.perf_counter() - start
    peak_kib = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", done.stderr).group(1))
    return wall, peak_kib / 2**20


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder")
    parser.add_argument("--make", action="store_true", help="write the frames first")
    parser.add_argument("--count", type=int, default=600)
    parser.add_argument("--height", type=int, default=2168)
    parser.add_argument("--width", type=int, default=4096)
    parser.add_argument("--window", type=int, default=200)
    parser.add_argument("--lag", type=int, default=5)
    parser.add_argument("--every", type=int, default=200)
    parser.add_argument("--max-lag", type=int, default=20)
    parser.add_argument("--also-max-lag", type=int, metavar="K", help="also run analyze --timeline with this K")
    parser.add_argument("--part", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.part:
        part(args.part, args.folder, args.window, args.lag, args.max_lag)
        return 0
    if args.make:
        make(Path(args.folder), args.count, args.height, args.width)
        return 0
    python = sys.executable
    shape = f"--window {args.window} --lag {args.lag} --max-lag {args.max_lag}".split()
    out = tempfile.mkdtemp(prefix="timeline-")
    timeline = [python, "-m", "edgedsm", "analyze", args.folder, "--timeline", out, *shape,
                "--every", str(args.every), "--no-progress"]
    runs = {}
    print(f"load average before: {os.getloadavg()[0]:.1f}")
    for name, command in (("decode", [python, __file__, args.folder, *shape, "--part", "decode"]),
                          ("decode + push, S1-S3", [python, __file__, args.folder, *shape, "--part", "push-s123"]),
                          ("decode + push, S1-S3 + τc", [python, __file__, args.folder, *shape, "--part", "push-tau"]),
                          ("analyze --timeline", timeline),
                          ("analyze --timeline --no-tau-c", [*timeline, "--no-tau-c"]),
                          *([(f"analyze --timeline --max-lag {args.also_max_lag}",
                              [*timeline, "--max-lag", str(args.also_max_lag)])] if args.also_max_lag else [])):
        runs[name] = measure(command)
        print(f"{name:32s} {runs[name][0]:7.1f} s  peak RSS {runs[name][1]:5.2f} GiB", flush=True)
    print(f"load average after: {os.getloadavg()[0]:.1f}")
    wall = runs["analyze --timeline"][0]
    for reference in ("decode + push, S1-S3", "decode + push, S1-S3 + τc"):
        print(f"analyze --timeline / ({reference}): {wall / runs[reference][0]:.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
