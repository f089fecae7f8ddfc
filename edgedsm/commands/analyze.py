"""Compute an activity map S1, S2 or S3 (paper Eq. 1-4) from a stack of frames.

The map is computed from WINDOW consecutive frames starting at --start, comparing frames LAG
apart: S1 = mean |I_i - I_{i+m}| (grey levels), S2 = mean |I_i - I_{i+m}|/(I_i + I_{i+m} + q)
(for uneven illumination), S3 = S1/σ with σ each pixel's temporal standard deviation
(robust to ambient light). Higher values mean faster processes (more activity).

With --timeline OUT_DIR it follows the activity against time instead (the paper's §3 reads
drying this way): a sliding window of N frames is sampled every --every frames, and
OUT_DIR/timeline.csv gets, per region and sample, the mean S1, S2, S3 and the region's τc
(frames and seconds); OUT_DIR/timeline.png plots them and OUT_DIR/histogram.png shows the
histogram of the S2 map (--histogram) against time. FRAMES may then also be a scene file
(or 'default'), simulated on the fly (--frames of them). Regions come from a daemon config
(-c), else the whole frame is one region named 'frame'.

Examples:
  edgedsm analyze frames.npy --estimator s1 --window 200 --lag 10 -o s1.npy --png
  edgedsm analyze frames/ --estimator s3 --window 50 --lag 4 -o s3.npy --png s3.png
  edgedsm analyze config/scenes/drying_demo.toml --frames 1200 --timeline out/ --window 100 --lag 2
  edgedsm analyze recording.npy --timeline out/ -c edgedsm.toml --dt 0.05
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from edgedsm.commands.timeline_output import add_timeline_arguments, run_timeline
from edgedsm.errors import EstimatorError
from edgedsm.estimators import s1, s2, s3
from edgedsm.imageio import read_stack, save_map_png

NAME = "analyze"
HELP = "compute an S1/S2/S3 activity map from frames"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("frames", metavar="FRAMES", help=".npy stack, multi-page .tif, or a folder of images")
    parser.add_argument("--estimator", choices=("s1", "s2", "s3"), default="s1",
                        help="s1: plain; s2: normalised by intensity; s3: normalised by σ (default s1)")
    parser.add_argument("--window", type=int, metavar="N", help="frames per map (default: all from --start)")
    parser.add_argument("--lag", type=int, default=1, metavar="m", help="time lag in frames (default 1)")
    parser.add_argument("--q", type=float, default=0.0, help="S2 only: added to the denominator (default 0)")
    parser.add_argument("--start", type=int, default=0, help="index of the first frame used (default 0)")
    parser.add_argument("-o", "--output", metavar="MAP.npy", help="float64 map as .npy (required without --timeline)")
    parser.add_argument("--png", nargs="?", const=True, metavar="PNG",
                        help="also write a colour-mapped picture (default: MAP.png beside the .npy)")
    parser.add_argument("--json", action="store_true", help="print the result as one JSON object")
    add_timeline_arguments(parser)


def run(args: argparse.Namespace) -> int:
    if args.timeline is not None:
        return run_timeline(args)
    if args.output is None:
        raise EstimatorError("give -o MAP.npy (or --timeline OUT_DIR)")
    stack = read_stack(args.frames)
    total = stack.shape[0]
    if not 0 <= args.start < total:
        raise EstimatorError(f"--start {args.start} is outside the {total} frames of {args.frames}")
    window = total - args.start if args.window is None else args.window
    if window < 2 or args.start + window > total:
        raise EstimatorError(f"--window {window} from --start {args.start} does not fit the {total} frames")
    frames = np.asarray(stack[args.start:args.start + window])
    if args.estimator == "s1":
        result = s1(frames, args.lag)
    elif args.estimator == "s2":
        result = s2(frames, args.lag, q=args.q)
    else:
        result = s3(frames, args.lag)
    output = Path(args.output)
    output.parent.mkdir(parents=True, exist_ok=True)
    np.save(output, result)
    message = (f"{args.estimator.upper()} from frames {args.start}..{args.start + window - 1}, lag {args.lag}: "
               f"mean {result.mean():.4g}, min {result.min():.4g}, max {result.max():.4g} -> {output}")
    png = None
    if args.png:
        png = output.with_suffix(".png") if args.png is True else Path(args.png)
        save_map_png(png, result, title=f"{args.estimator.upper()}  N={window}  m={args.lag}")
        message += f", {png}"
    if args.json:
        print(json.dumps({"estimator": args.estimator, "start": args.start, "window": window, "lag": args.lag,
                          "shape": list(result.shape), "mean": float(result.mean()), "min": float(result.min()),
                          "max": float(result.max()), "output": str(output),
                          "png": str(png) if png is not None else None}))
    else:
        print(message)
    return 0
