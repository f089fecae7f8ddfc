"""What the longer default τc ladder costs the streaming engine: push time and memory per pixel
with K = 20 (the old default for m = 10) and K = N/2 (the new one), S1+S2+S3 alone for scale.

Each configuration pushes the same random 8-bit frames; the time per push is the best of
--repeats rounds of --pushes pushes after the window is full (rounds interleaved across the
configurations, so a load change on a shared machine hits them alike).

    python scripts/tau_longest_lag_cost.py [--size 1024] [--window 200] [--lag 10]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from edgedsm.estimators import SlidingWindow
from edgedsm.estimators.correlation_time import default_max_lag


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=1024)
    parser.add_argument("--window", type=int, default=200)
    parser.add_argument("--lag", type=int, default=10)
    parser.add_argument("--pushes", type=int, default=40)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, (args.size, args.size), dtype=np.uint8) for _ in range(16)]
    n, full = args.window, default_max_lag(args.window)
    configs = {}
    for mode in ("sliding", "tumbling"):
        configs[(mode, "S1+S2+S3")] = SlidingWindow((args.size,) * 2, n, args.lag, mode=mode)
        for k in (20, full):
            configs[(mode, f"+ τc, K = {k}")] = SlidingWindow((args.size,) * 2, n, args.lag, mode=mode, max_lag=k,
                                                            estimators=("s1", "s2", "s3", "tau_c"))
    for engine in configs.values():
        for i in range(n + 16):
            engine.push(frames[i % 16])
    best = dict.fromkeys(configs, float("inf"))
    for _ in range(args.repeats):
        for key, engine in configs.items():
            start = time.perf_counter()
            for i in range(args.pushes):
                engine.push(frames[i % 16])
            best[key] = min(best[key], (time.perf_counter() - start) / args.pushes)
    print(f"{args.size}², N = {n}, m = {args.lag}, 8-bit; best of {args.repeats} x {args.pushes} pushes")
    print("| mode | estimators | lags | push (ms) | vs K = 20 | bytes per pixel |")
    print("|---|---|---:|---:|---:|---:|")
    for (mode, name), engine in configs.items():
        lags = engine.tau_lags.size if "τc" in name else 0
        ratio = best[(mode, name)] / best[(mode, "+ τc, K = 20")] if "τc" in name else float("nan")
        print(f"| {mode} | {name} | {lags} | {1e3 * best[(mode, name)]:.1f} | "
              f"{'' if ratio != ratio else f'{ratio:.2f}x'} | {engine.bytes_per_pixel:.0f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
