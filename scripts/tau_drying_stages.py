"""τc through the stages of a simulated drying film: the default longest lag (N/2) against K = 20.

Issue 23 item 4: with K = 20 every stage after the first read "above 20". This simulates
config/scenes/darkening_film.toml (τc from 2 to 200 frames while the light falls to a tenth,
shot noise, dark current, 8 bits, 128², 1200 frames), runs `edgedsm.timeline.timeline` on
disjoint sets of N = 200 frames (the paper's processing) with K = 20 and with the default
K = N/2, and prints per set the scene's τc at the set's centre, the mean grey level, and both
fits (frames; "> K" = status above, "< 1/3" = below).

    python scripts/tau_drying_stages.py [--window 200] [--frames 1200]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from edgedsm.estimators.correlation_time import default_max_lag
from edgedsm.sim import Simulator
from edgedsm.sim.scene import load_scene
from edgedsm.timeline import timeline

SCENE = Path(__file__).resolve().parent.parent / "config" / "scenes" / "darkening_film.toml"


def reading(tau: float, status: str) -> str:
    return {"above": f"> {tau:.0f}", "below": "< 1/3", "no_signal": "no signal"}.get(status, f"{tau:.1f}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--window", type=int, default=200)
    parser.add_argument("--frames", type=int, default=1200)
    args = parser.parse_args()
    scene = load_scene(SCENE)
    frames = list(Simulator(scene).frames(args.frames))
    regions = {"film": np.ones(frames[0].shape, bool)}
    n = args.window
    runs = {k: timeline(iter(frames), regions, n, 5, n, max_lag=k, bits=scene.detector.bits)
            for k in (20, default_max_lag(n))}
    short, full = runs[20], runs[default_max_lag(n)]
    print(f"| frames | scene τc at the set's centre | mean grey | τc, K = 20 | τc, K = N/2 = {default_max_lag(n)} |")
    print("|---|---:|---:|---:|---:|")
    for row_short, row_full in zip(short.rows, full.rows, strict=True):
        end = row_short[0]
        centre = end - (n - 1) / 2
        true = scene.activity.tau_c * scene.activity.drying.factor(centre)
        mean = float(np.mean([frame.mean() for frame in frames[end - n + 1:end + 1]]))
        print(f"| {end - n + 1}–{end} | {true:.1f} | {mean:.0f} | {reading(row_short[6], row_short[8])} | "
              f"{reading(row_full[6], row_full[8])} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
