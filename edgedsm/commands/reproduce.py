"""Reproduce the noise analysis of the reference paper's §2 (Figs. 2-7) on simulated speckle.

Simulates the paper's two test objects — a surface of constant activity and the two-level
logo object ("IOMT", "ETRI") — with and without phase noise (vibration: α, τ_noise) and
ambient light (η), computes S1, S2 and S3 (Eq. 1-4) and writes into the output directory:

  report.md          tables with the numbers, and which of the paper's findings they confirm
  fig2_*.png         histograms and half-GT/half-noisy maps at constant activity (Fig. 2)
  fig3_maps.png      S1 maps and contrast β for α = 0 ... 0.5 (Fig. 3)
  fig4_maps.png      S2 against S3 under Gaussian light and ambient light (Fig. 4)
  fig5_7_beta.png    β, S_l, S_b against τ_noise for three phase-noise readings (Figs. 5-7)
  results.json       every number, per seed

The full run (256x256 px, N = 200 frames, 3 seeds, ~140 simulations) takes about 5-8 minutes
on two cores; --quick (96 px, 100 frames, one seed, fewer α and τ_noise values) takes about
10 seconds and is meant for checking the set-up, not for conclusions.

Examples:
  edgedsm reproduce                           # writes docs/reproduction/
  edgedsm reproduce --quick -o /tmp/repro     # a fast look
  edgedsm reproduce --seed 7 --repeats 5 -o out/seed7
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import TYPE_CHECKING

from edgedsm.commands.common import lab_module

if TYPE_CHECKING:
    from tqdm import tqdm

NAME = "reproduce"
HELP = "reproduce the paper's §2 noise analysis (Figs. 2-7) as a markdown report with figures"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("-o", "--output", default="docs/reproduction", metavar="DIR",
                        help="directory for report.md, the PNG figures and results.json "
                             "(default: %(default)s)")
    parser.add_argument("--quick", action="store_true",
                        help="small and fast (caps size at 96 px and frames at 100, one seed, "
                             "fewer α and τ_noise values): seconds instead of minutes")
    parser.add_argument("--size", type=int, default=256, metavar="PX",
                        help="camera pixels per side, Nx = Ny (default: %(default)s, the paper's)")
    parser.add_argument("--frames", type=int, default=200, metavar="N",
                        help="frames per simulation, the window N (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=1,
                        help="first seed; GT and noisy runs share it (default: %(default)s)")
    parser.add_argument("--repeats", type=int, metavar="K",
                        help="seeds averaged in Figs. 3-7 (default: 3, or 1 with --quick)")
    parser.add_argument("--no-progress", dest="progress", action="store_false",
                        help="do not show a progress bar")


def run(args: argparse.Namespace) -> int:
    # the lab's report, loaded by name here: it installs apart (exit 69 with how, when it is missing) and
    # pulls in scipy.stats, which every other command can do without
    lab = lab_module("edgedsm_lab.report", "edgedsm reproduce")
    Settings, plan_runs, reproduce = lab.Settings, lab.plan_runs, lab.reproduce

    settings = Settings.make(size=args.size, frames=args.frames, seed=args.seed,
                             repeats=args.repeats, quick=args.quick)
    runs = len(plan_runs(settings))
    print(f"reproduce: {runs} simulations of {settings.frames} frames at "
          f"{settings.size}x{settings.size} px -> {args.output}", file=sys.stderr)

    def progress(total: int) -> tqdm:  # the lab's ProgressBar
        from tqdm import tqdm

        return tqdm(total=total, desc="reproduce", unit="frame", file=sys.stderr,
                    disable=None if args.progress else True, leave=False)

    start = time.perf_counter()
    report = reproduce(args.output, size=args.size, frames=args.frames, quick=args.quick,
                       progress=progress, seed=args.seed, repeats=args.repeats)
    print(f"wrote {report} and its figures in {time.perf_counter() - start:.0f} s")
    return 0
