"""Simulate dynamic speckle frames from a scene file (paper §2A model).

The scene (TOML) says which effects to simulate: activity (τc map, drying), illumination,
phase noise, ambient light, detector. Effects that are absent cost nothing. See
config/scenes/*.toml for examples and the README's "Scenes" section for the format.

Examples:
  edgedsm simulate config/scenes/logos.toml -o frames.npy
  edgedsm simulate default -o out/%05d.png --frames 50
  edgedsm simulate config/scenes/constant.toml -o stack.tif --seed 7
"""

from __future__ import annotations

import argparse
import sys
import time

from edgedsm.commands.common import add_progress_flag, progress, scene_argument
from edgedsm.imageio import write_stack

NAME = "simulate"
HELP = "simulate speckle frames from a scene file"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", metavar="SCENE", help="scene TOML file, or 'default' for the built-in logo scene")
    parser.add_argument("-o", "--output", required=True, metavar="OUT",
                        help="OUT.npy (N,H,W stack), OUT.tif (multi-page) or 'dir/%%05d.png' (image sequence)")
    parser.add_argument("--frames", type=int, metavar="N", help="number of frames (default: the scene's)")
    parser.add_argument("--seed", type=int, help="override the scene's seed")
    parser.add_argument("--precision", choices=("single", "double"), default="single",
                        help="field precision: single = complex64 (fast), double = complex128")
    parser.add_argument("--workers", type=int, default=1,
                        help="simulator threads for draws, FFTs and detector (default 1; results do not depend on it)")
    add_progress_flag(parser)


def run(args: argparse.Namespace) -> int:
    from edgedsm.sim import Simulator  # here: keeps the CLI's start-up light
    scene = scene_argument(args.scene)
    if args.seed is not None:
        scene.scene.seed = args.seed
    count = args.frames if args.frames is not None else scene.scene.frames
    if count < 1:
        raise SystemExit("edgedsm simulate: --frames must be >= 1")
    simulator = Simulator(scene, precision=args.precision, workers=args.workers)
    start = time.perf_counter()
    frames = progress(simulator.frames(count), count, "simulate", args.progress)
    written = write_stack(args.output, frames, count)
    elapsed = time.perf_counter() - start
    print(f"wrote {count} frames of {scene.scene.size}x{scene.scene.size} {simulator.output_dtype} "
          f"to {written} in {elapsed:.1f} s ({count / elapsed:.0f} frames/s); "
          f"effects: {', '.join(simulator.effects)}", file=sys.stdout)
    return 0
