"""Simulator benchmark: frames/s per effect, complex64 against complex128, pyspeckle as a peer.

Measures, side by side in one run:

  1. frames/s of the simulator at 256² and 512² camera pixels (object grid 512², 1024²) with
     1 thread and with every core, for the bare model and with each effect switched on alone,
     and what each effect costs in ms per frame;
  2. complex64 against complex128: frames/s, and what the precision changes in the results:
     the S1/S2/S3 maps (and the activity contrast β) computed from a single and a double run
     of the same seeded scene, which share every random draw and differ only by rounding;
  3. pyspeckle's static speckle generator (create_Exponential) at the same sizes, as a peer.

Timing: each case runs a few warm-up frames, then many short trials of n frames, interleaved
over the cases so that load from elsewhere hits all of them alike; the tables give the best
trial (the least disturbed), the median in brackets where it is > 10 % slower, and the CPU
time per frame (all threads), which other load hardly changes.

Examples:
  edgedsm bench sim                              # full run, several minutes
  edgedsm bench sim --quick                      # a short run
  edgedsm bench sim --output docs/bench-sim.md   # also write the markdown report
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from edgedsm.analysis import contrast
from edgedsm.estimators.batch import all_maps
from edgedsm.sim import Scene, Simulator, region_masks, scene_from_dict
from edgedsm_lab.bench.report import (
    SHARED_ABOVE,
    Report,
    add_output_argument,
    cpu_sample,
    format_load,
    load_average,
    others_share,
)

HELP = "simulator frames/s per effect, complex64 vs complex128 (and what it changes), vs pyspeckle"

SPECKLE_SIZE = 2.0
TAU_BACKGROUND, TAU_REGION = 50.0, 10.0


@dataclass(frozen=True)
class Case:
    """One benchmarked configuration: the scene tables added to the bare model."""

    key: str
    label: str
    tables: dict
    reference: str | None = "base"  # the cost of the effect is measured against this case


DETECTOR = {"n_max": 1000, "bits": 8}
CASES = (
    Case("base", "base: surface + activity + propagation + 2x2 pixels", {}, None),
    Case("gauss", "+ Gaussian illumination (Ω = size)", {"illumination": {"kind": "gaussian"}}),
    Case("white", "+ phase noise, white (α = 0.2)", {"phase_noise": {"alpha": 0.2}}),
    Case("ou", "+ phase noise, OU (α = 0.2, τ_noise = 5)",
         {"phase_noise": {"alpha": 0.2, "tau_noise": 5.0, "model": "ou"}}),
    Case("drying", "+ drying (τc × 100 over 1000 frames)",
         {"drying": {"law": "exponential", "duration": 1000, "final_factor": 100.0}}),
    Case("quant", "+ detector without shot noise (gain, range, 8 bit)",
         {"detector": {**DETECTOR, "shot_noise": False}}),
    Case("shot", "+ detector with shot noise (N_max = 1000, 8 bit)", {"detector": DETECTOR}),
    Case("ambient", "+ ambient light (η = 0.2), on top of the detector",
         {"detector": DETECTOR, "ambient_light": {"eta": 0.2}}, "shot"),
    Case("all", "all effects: Gaussian, OU noise, drying, detector, ambient light",
         {"illumination": {"kind": "gaussian"},
          "phase_noise": {"alpha": 0.2, "tau_noise": 5.0, "model": "ou"},
          "drying": {"law": "exponential", "duration": 1000, "final_factor": 100.0},
          "detector": DETECTOR, "ambient_light": {"eta": 0.2}}),
)


def poisson_kernel() -> str:
    """What the simulator's detector draws its Poisson counts with: the numba kernel whenever numba
    imports (edgedsm.sim.poisson), else NumPy; asked without importing numba here."""
    return "numba" if importlib.util.find_spec("numba") is not None else "numpy"


def make_scene(size: int, tables: dict, seed: int = 1) -> Scene:
    """Two activity levels (a square of τc = 10 on τc = 50) plus the given effect tables."""
    third = size // 3
    activity: dict = {"tau_c": TAU_BACKGROUND, "regions": [
        {"shape": "rect", "x": third, "y": third, "width": third, "height": third,
         "tau_c": TAU_REGION, "name": "active"}]}
    data: dict = {"scene": {"size": size, "seed": seed, "speckle_size": SPECKLE_SIZE}, "activity": activity}
    for name, table in tables.items():
        if name == "drying":
            activity["drying"] = table
        elif name == "illumination":
            data[name] = {**table, "omega": float(size)}
        else:
            data[name] = table
    return scene_from_dict(data)


@dataclass
class Timing:
    """Seconds per frame of each trial: wall clock, and CPU time of the whole process."""

    trials: list[float] = field(default_factory=list)
    cpu: list[float] = field(default_factory=list)

    @property
    def best(self) -> float:
        return min(self.trials)

    @property
    def median(self) -> float:
        return statistics.median(self.trials)

    @property
    def cpu_best(self) -> float:
        """Least CPU time per frame (all threads): what the work costs, little affected by load."""
        return min(self.cpu)

    def fps(self) -> str:
        text = f"{1.0 / self.best:.0f}"
        if self.median > 1.1 * self.best:
            text += f" ({1.0 / self.median:.0f})"
        return text


def measure(steps: dict[str, Callable[[], object]], frames: dict[str, int], repeats: int,
            warmup: int = 2) -> dict[str, Timing]:
    """Best-of-``repeats`` timing of each step function, trials interleaved over the cases."""
    for step in steps.values():
        for _ in range(warmup):
            step()
    timings = {key: Timing() for key in steps}
    for _ in range(repeats):
        for key, step in steps.items():
            count = frames[key]
            cpu = time.process_time()
            start = time.perf_counter()
            for _ in range(count):
                step()
            timings[key].trials.append((time.perf_counter() - start) / count)
            timings[key].cpu.append((time.process_time() - cpu) / count)
    return timings


def frame_step(simulator: Simulator) -> Callable[[], object]:
    """next_frame (detector output, or float intensity without a detector)."""
    return simulator.next_frame


def pyspeckle_step(size: int) -> Callable[[], object] | None:
    """One static speckle pattern of pyspeckle at the same size and speckle size, or None."""
    try:
        import pyspeckle
    except ImportError:
        return None
    return lambda: pyspeckle.create_Exponential(size, round(SPECKLE_SIZE))  # needs an int


# -- precision: what complex128 changes in the maps -----------------------------------------
@dataclass
class PrecisionRow:
    case: str
    estimator: str
    max_rel: float  # max |S_single - S_double| / spread(S_double)
    rms_rel: float  # rms (S_single - S_double) / spread(S_double)
    seed_rms_rel: float  # rms (S_double(seed 1) - S_double(seed 2)) / spread: the statistical scale
    beta_single: float
    beta_double: float


def precision_study(size: int, frames: int, lag: int, workers: int) -> tuple[list[PrecisionRow], dict]:
    """Maps from single and double runs of the same seeded scenes; differences and contrast."""
    rows: list[PrecisionRow] = []
    extra: dict = {}
    cases = {"float intensities, no noise": {},
             "all effects, 8-bit detector": next(c.tables for c in CASES if c.key == "all")}
    for name, tables in cases.items():
        scene = make_scene(size, tables)
        masks = region_masks(scene)
        stacks = {}
        for label, precision, seed in (("single", "single", 1), ("double", "double", 1), ("seed2", "double", 2)):
            simulator = Simulator(make_scene(size, tables, seed), precision=precision, workers=workers)
            stacks[label] = np.stack([simulator.next_frame() for _ in range(frames)])
        single, double = stacks["single"].astype(np.float64), stacks["double"].astype(np.float64)
        if scene.detector is None:
            last = np.abs(single[-1] - double[-1])
            extra[name] = (f"frame {frames}: max |ΔI|/<I> = {last.max() / double[-1].mean():.1e}, "
                           f"rms ΔI/σ_I = {np.sqrt((last**2).mean()) / double[-1].std():.1e}")
        else:
            differ = (stacks["single"] != stacks["double"])
            extra[name] = (f"{differ.mean() * 100:.4f} % of the 8-bit pixel values differ "
                           f"(by at most {int(np.abs(single - double).max())} grey levels)")
        maps_s, maps_d = all_maps(single, lag), all_maps(double, lag)
        maps_2 = all_maps(stacks["seed2"].astype(np.float64), lag)
        for estimator in ("s1", "s2", "s3"):
            a, b = maps_s[estimator], maps_d[estimator]
            spread = float(b.std()) or 1.0
            rows.append(PrecisionRow(
                name, estimator, float(np.abs(a - b).max()) / spread,
                float(np.sqrt(((a - b) ** 2).mean())) / spread,
                float(np.sqrt(((maps_2[estimator] - b) ** 2).mean())) / spread,
                contrast(a, masks["active"], masks["background"]),
                contrast(b, masks["active"], masks["background"])))
    return rows, extra


def precision_drift(size: int, checkpoints: tuple[int, ...]) -> list[tuple[int, float]]:
    """rms (I_single - I_double)/σ_I of the float intensity at each checkpoint frame.

    The float32 phase random walk rounds at every step; its error grows like sqrt(frames).
    """
    scene = make_scene(size, {"phase_noise": {"alpha": 0.2, "tau_noise": 5.0, "model": "ou"}})
    single, double = Simulator(scene, "single"), Simulator(scene, "double")
    out = []
    for frame in range(1, max(checkpoints) + 1):
        a, b = single.next_intensity(), double.next_intensity()
        if frame in checkpoints:
            out.append((frame, float(np.sqrt(((a - b) ** 2).mean()) / b.std())))
    return out


# -- report ---------------------------------------------------------------------------------


def run(args: argparse.Namespace) -> int:
    quick = args.quick
    sizes = args.sizes
    workers = sorted({1, args.workers or os.cpu_count() or 1})
    repeats = args.repeats or (3 if quick else 15)

    def frames_for(size: int) -> int:
        if args.frames:
            return args.frames
        return max(2, int((15 if quick else 40) * (256 / size) ** 2))

    report = Report("Simulator benchmark")
    emit = report.line
    emit(report.machine(f"edgedsm bench sim{' --quick' if quick else ''}", "scipy", "pyspeckle", "numba"))
    emit(f"Threads: `workers` = {' and '.join(map(str, workers))} (the simulator's threads for random "
         f"draws, FFTs and detector; scipy.fft itself runs single-threaded inside them); detector "
         f"Poisson kernel: {poisson_kernel()}. Speckle size "
         f"{SPECKLE_SIZE:g} px, a square of τc = {TAU_REGION:g} on a background of τc = {TAU_BACKGROUND:g}. "
         f"Frames/s of `next_frame()`: best of {repeats} trials of n frames (n = "
         + ", ".join(f"{frames_for(s)} at {s}²" for s in sizes)
         + "), trials interleaved over the cases; the median is in brackets where it is > 10 % slower.")
    emit()

    # 1. per effect ------------------------------------------------------------------------
    steps: dict[str, Callable[[], object]] = {}
    counts: dict[str, int] = {}
    simulators: dict[str, Simulator] = {}
    for size in sizes:
        for case in CASES:
            for w in workers:
                key = f"{case.key}/{size}/{w}/single"
                simulators[key] = Simulator(make_scene(size, case.tables), workers=w)
                steps[key] = frame_step(simulators[key])
                counts[key] = frames_for(size)
        for w in workers:
            key = f"all/{size}/{w}/double"
            sim = Simulator(make_scene(size, next(c.tables for c in CASES if c.key == "all")),
                            precision="double", workers=w)
            steps[key], counts[key] = frame_step(sim), frames_for(size)
        peer = pyspeckle_step(size)
        if peer is not None:
            steps[f"pyspeckle/{size}"], counts[f"pyspeckle/{size}"] = peer, frames_for(size)
    print(f"timing {len(steps)} cases ...", file=sys.stderr, flush=True)
    load_before, start = load_average(), cpu_sample()
    timings = measure(steps, counts, repeats)
    others = others_share(start, cpu_sample())
    took = "unknown" if others is None else f"{others:.1%}"
    emit(f"Other work took {took} of the machine's CPU time during the timing (1-minute load average "
         f"before / after it: {format_load(load_before)} / {format_load(load_average())}); "
         f"anything above ~{SHARED_ABOVE:.0%} means other programs shared the {os.cpu_count()} CPUs and the "
         "two-thread figures in particular are low.")
    emit()

    emit("## Frames per second by effect (complex64)")
    emit()
    header = ["case"]
    for size in sizes:
        header += [f"{size}², {w} thr. fps" for w in workers] + [f"{size}² cost, CPU ms/frame"]
    table = []
    for case in CASES:
        cells = [case.label]
        for size in sizes:
            cells += [timings[f"{case.key}/{size}/{w}/single"].fps() for w in workers]
            own = timings[f"{case.key}/{size}/1/single"].cpu_best
            if case.reference is None:
                cells.append(f"{own * 1e3:.2f} (total)")
            else:
                ref = timings[f"{case.reference}/{size}/1/single"].cpu_best
                cells.append(f"{(own - ref) * 1e3:+.2f}")
        table.append(cells)
    report.table(header, table)
    emit()
    emit("Cost: extra CPU time per frame over the base (the ambient light: over the detector with "
         "shot noise), 1 thread, least of the trials (CPU time is little affected by other load); a "
         "difference of two measurements, so ±0.2 ms means 'free'. An effect that is absent draws "
         "no random numbers and costs nothing.")
    emit()

    # 2. precision -------------------------------------------------------------------------
    emit("## complex64 against complex128 (all effects)")
    emit()
    table = []
    for size in sizes:
        for w in workers:
            single, double = timings[f"all/{size}/{w}/single"], timings[f"all/{size}/{w}/double"]
            table.append([f"{size}²", w, single.fps(), double.fps(), f"{single.cpu_best * 1e3:.2f}",
                          f"{double.cpu_best * 1e3:.2f}", f"{double.cpu_best / single.cpu_best:.2f}"])
    report.table(["size", "threads", "complex64 fps", "complex128 fps", "complex64 CPU ms/frame",
                  "complex128 CPU ms/frame", "complex128 / complex64 (CPU)"], table)
    emit()
    emit("Most of the extra cost of complex128 is not the FFT (1.8x) but sin/cos/log: numpy "
         "vectorises them (AVX-512/AVX2) for float32 only; float64 sin and cos are scalar libm "
         "calls, ~20x slower per value here.")
    emit()
    acc_size = min(sizes) if quick else 256
    acc_frames = args.accuracy_frames or (40 if quick else 200)
    lag = 2
    print(f"precision study at {acc_size}², {acc_frames} frames ...", file=sys.stderr, flush=True)
    rows, extra = precision_study(acc_size, acc_frames, lag, max(workers))
    emit(f"What the precision changes: the same seeded scene at {acc_size}², {acc_frames} frames, run in "
         f"single and in double precision (the two runs share every random draw and differ only by "
         f"rounding), maps over all {acc_frames} frames with lag m = {lag}. ΔS = S(complex64) - "
         f"S(complex128); spread = standard deviation of the complex128 map over the image; "
         f"β = (S_active - S_background)/S_active.")
    emit()
    report.table(["scene", "map", "max |ΔS| / spread", "rms ΔS / spread", "rms ΔS / spread, another seed",
                  "β complex64", "β complex128"],
                 [[row.case, row.estimator.upper(), f"{row.max_rel:.1e}", f"{row.rms_rel:.1e}",
                   f"{row.seed_rms_rel:.2f}", f"{row.beta_single:.6f}", f"{row.beta_double:.6f}"]
                  for row in rows], align="llrrrrr")
    emit()
    for name, text in extra.items():
        emit(f"- {name}: {text}.")
    drift_size = min(64, acc_size)
    checkpoints = (10, 100, 1000) if quick else (10, 100, 1000, 10000)
    print(f"precision drift at {drift_size}², {checkpoints[-1]} frames ...", file=sys.stderr, flush=True)
    drift = precision_drift(drift_size, checkpoints)
    emit(f"- drift of the float32 phase walk ({drift_size}², OU phase noise): rms ΔI/σ_I = "
         + ", ".join(f"{value:.1e} after {frame} frames" for frame, value in drift) + ".")
    emit()
    emit("'another seed' is the difference between two equally valid runs (the statistical noise "
         "of the maps): the precision changes the maps by orders of magnitude less.")
    emit()

    # 3. peer ------------------------------------------------------------------------------
    emit("## Peer: pyspeckle")
    emit()
    if not any(key.startswith("pyspeckle/") for key in timings):
        emit("pyspeckle is not installed (`pip install edgedsm[peers]`); no peer timing.")
    else:
        table = [[f"pyspeckle `create_Exponential(M, {SPECKLE_SIZE:g})`",
                  "one static pattern, independent of the last (no time correlation, no noise, "
                  "no detector), complex128", *(timings[f"pyspeckle/{s}"].fps() for s in sizes)],
                 ["edgedsm base, 1 thread, complex64", "next frame of a dynamic pattern (random walk "
                  "per grid point, τc map), 2x2 pixels", *(timings[f"base/{s}/1/single"].fps() for s in sizes)]]
        table += [[f"edgedsm all effects, {w} thr., complex64", "the same plus Gaussian light, OU noise, "
                   "drying, shot noise, ambient light, 8-bit output",
                   *(timings[f"all/{s}/{w}/single"].fps() for s in sizes)] for w in workers]
        report.table(["generator", "one frame is", *(f"{s}² fps" for s in sizes)], table,
                     align="ll" + "r" * len(sizes))
        emit()
        emit(f"pyspeckle draws an M·{SPECKLE_SIZE:g} square of random phases and does one complex128 "
             "fft2 of it (the same grid as ours at this speckle size), with numpy's single-threaded FFT.")
    emit()
    if args.output:
        report.save(args.output)
    return 0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true", help="fewer frames and trials (about half a minute)")
    parser.add_argument("--sizes", type=int, nargs="+", default=[256, 512], metavar="N",
                        help="camera sizes N (N x N pixels; default 256 512)")
    parser.add_argument("--workers", type=int, metavar="W",
                        help="thread count to compare with 1 thread (default: all logical CPUs)")
    parser.add_argument("--frames", type=int, metavar="n", help="frames per trial (default: by size)")
    parser.add_argument("--repeats", type=int, metavar="R", help="trials per case (default 15; 3 with --quick)")
    parser.add_argument("--accuracy-frames", type=int, metavar="n",
                        help="frames of the single/double precision study (default 200; 40 with --quick)")
    add_output_argument(parser, "docs/bench-sim.md")
