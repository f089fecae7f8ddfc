"""Drying kinetics over decades (docs/kinetics.md): the time-resolved correlation's τ(t)
(:mod:`edgedsm.estimators.kinetics`) against the simulated film's truth
(:func:`edgedsm.sim.activity.decorrelation_lags`), beside the window τc of the same frames
(:func:`edgedsm.estimators.correlation_time.tau_c_bounds`), on a film whose τc grows
exponentially over four decades; then the same film with ambient light, a Gaussian beam, a
darkening film and phase noise, each alone; then the cost per frame against one S1 push and the
memory. Writes the figure (PNG) and prints the tables docs/kinetics.md quotes.

    edgedsm bench kinetics [--quick] [--figure docs/kinetics.png] [-o FILE.md]
"""

from __future__ import annotations

import argparse
import math
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from edgedsm.estimators.correlation_time import ABOVE as WINDOW_ABOVE
from edgedsm.estimators.correlation_time import MEASURED as WINDOW_MEASURED
from edgedsm.estimators.correlation_time import tau_c_bounds
from edgedsm.estimators.kinetics import Kinetics, slot_schedule
from edgedsm.estimators.noise import NoiseModel
from edgedsm.sim import Simulator, scene_from_dict
from edgedsm.sim.activity import decorrelation_lags
from edgedsm.sim.detector import DetectorRows
from edgedsm_lab.bench.report import Report, add_output_argument, load_average

HELP = "drying kinetics over decades: τ(t) of the time-resolved correlation against the truth (docs/kinetics.md)"
#: Each variant adds one effect to the plain film (scene tables; "{size}" and "{frames}" filled in).
VARIANTS: dict[str, dict] = {
    "plain": {},
    "ambient η=0.3": {"ambient_light": {"eta": 0.3}},
    "Gaussian beam Ω=size/2": {"illumination": {"kind": "gaussian", "omega": "{half}"}},
    "darkening to 0.1": {"darkening": {"duration": "{frames}", "final_factor": 0.1}},
    "phase noise α=0.3": {"phase_noise": {"alpha": 0.3, "tau_noise": 1.0, "model": "white"}},
}
TOLERANCE = 0.25  # the bound on the median relative error
SAMPLING = 4  # the cost's sampling mask: every 4th pixel of the region in each direction


@dataclass(frozen=True)
class Case:
    """One film: size² pixels, τc from ``tau_start`` growing ``final_factor``-fold exponentially
    over ``frames`` frames; kinetics kept up to ``longest_age`` frames at ``per_octave``; measured
    every ``stride`` frames; the window τc over ``window`` frames up to lag ``max_lag`` every
    ``window_every`` frames."""

    size: int = 48
    frames: int = 60_000
    tau_start: float = 2.0
    final_factor: float = 1e4
    longest_age: int = 4096
    per_octave: int = 4
    stride: int = 10
    window: int = 128
    max_lag: int = 64
    window_every: int = 500
    seed: int = 1
    variants: tuple[str, ...] = tuple(VARIANTS)


QUICK = Case(size=32, frames=12_000, longest_age=1024, window_every=400, variants=("plain",))


@dataclass
class Run:
    """One variant: sample frames, truth, τ (NaN where no number) and status for the flattened
    (default) and plain Eq. 1 estimators, the default's τ with a white step taken out
    (``measure(white=True)``), and the window τc (frames) with its status."""

    variant: str
    frames: np.ndarray
    truth: np.ndarray
    tau: np.ndarray
    status: list[str]
    tau_plain: np.ndarray
    status_plain: list[str]
    window_frames: np.ndarray
    window_tau: np.ndarray
    window_status: np.ndarray
    tau_white: np.ndarray = field(default_factory=lambda: np.zeros(0))
    seconds: float = 0.0


@dataclass
class Result:
    case: Case
    runs: dict[str, Run] = field(default_factory=dict)


def scene_of(case: Case, variant: str):
    """The scene of one variant of the film (the plain film plus the variant's one effect)."""
    extra = {table: {key: _fill(value, case) for key, value in spec.items()}
             for table, spec in VARIANTS[variant].items()}
    data = {"scene": {"size": case.size, "frames": case.frames, "seed": case.seed},
            "activity": {"tau_c": case.tau_start,
                         "drying": {"duration": case.frames, "final_factor": case.final_factor}},
            "detector": {"n_max": 1000.0, "bits": 8}, **extra}
    return scene_from_dict(data)


def _fill(value: object, case: Case) -> object:
    if value == "{half}":
        return case.size / 2
    if value == "{frames}":
        return case.frames
    return value


def noise_model(scene) -> NoiseModel:
    """The simulator's camera as a noise model: K = its grey levels per photon (quantum efficiency
    1, no read noise, dark level 0; dark current, when simulated, as the dark level and variance)."""
    detector = DetectorRows(scene)
    dark = scene.detector.dark_current
    return NoiseModel(gain=detector.scale, dark_mean=dark * detector.scale, dark_variance=dark * detector.scale**2,
                      quantized=scene.detector.quantization, source="simulator")


def run_variant(case: Case, variant: str) -> Run:
    """Simulate one variant and measure τ(t) every ``stride`` frames and the window τc."""
    scene = scene_of(case, variant)
    model = noise_model(scene)
    mask = np.ones((case.size, case.size), bool)
    kinetics = Kinetics(mask, model, case.longest_age, case.per_octave)
    plain = Kinetics(mask, model, case.longest_age, case.per_octave, flatten=0)
    simulator = Simulator(scene)
    recent: deque[np.ndarray] = deque(maxlen=case.window)
    samples, taus, statuses, taus_plain, statuses_plain, taus_white = [], [], [], [], [], []
    window_at, window_tau, window_status = [], [], []
    start = time.perf_counter()
    for index in range(case.frames):
        frame = simulator.next_frame()
        kinetics.push(frame)
        plain.push(frame)
        recent.append(frame)
        if index % case.stride == 0 and index > 0:
            samples.append(index)
            for estimator, tau_list, status_list in ((kinetics, taus, statuses), (plain, taus_plain, statuses_plain)):
                result = estimator.measure()
                tau_list.append(math.nan if result.tau is None else result.tau)
                status_list.append(result.status)
            white = kinetics.measure(white=True).tau
            taus_white.append(math.nan if white is None else white)
        if index % case.window_every == 0 and len(recent) == case.window:
            fit = tau_c_bounds(np.stack(recent), case.max_lag, mask)
            window_at.append(index)
            window_tau.append(float(fit.tau))
            window_status.append(int(fit.status))
    frames = np.asarray(samples, np.int64)
    return Run(variant, frames, decorrelation_lags(scene, frames), np.asarray(taus), statuses,
               np.asarray(taus_plain), statuses_plain, np.asarray(window_at, np.int64), np.asarray(window_tau),
               np.asarray(window_status), np.asarray(taus_white), time.perf_counter() - start)


def measure(case: Case) -> Result:
    result = Result(case)
    for variant in case.variants:
        result.runs[variant] = run_variant(case, variant)
    return result


@dataclass(frozen=True)
class Score:
    """Over the samples whose truth is 1 frame .. the longest age: the median relative error
    |τ/truth - 1| (a sample with no number counts as an infinite error), the median τ/truth, the
    share of samples with a number, and the truth's range covered."""

    median_error: float
    median_ratio: float
    share_ok: float
    samples: int
    truth_low: float
    truth_high: float


def score(truth: np.ndarray, tau: np.ndarray, longest_age: int) -> Score:
    inside = (truth >= 1.0) & (truth <= longest_age)
    if not inside.any():
        return Score(math.inf, math.nan, 0.0, 0, math.nan, math.nan)
    ratio = tau[inside] / truth[inside]
    error = np.where(np.isfinite(ratio), np.abs(ratio - 1.0), np.inf)
    finite = ratio[np.isfinite(ratio)]
    return Score(float(np.median(error)), float(np.median(finite)) if finite.size else math.nan,
                 float(np.isfinite(ratio).mean()), int(inside.sum()), float(truth[inside].min()),
                 float(truth[inside].max()))


def decade_rows(run: Run, longest_age: int) -> list[list[str]]:
    """Median τ/truth and the share with a number, per decade of the truth."""
    rows = []
    for low in (1.0, 10.0, 100.0, 1000.0):
        high = min(10.0 * low, float(longest_age))
        inside = (run.truth >= low) & (run.truth < high)
        if not inside.any():
            continue
        ratio = run.tau[inside] / run.truth[inside]
        finite = ratio[np.isfinite(ratio)]
        rows.append([f"{low:g}–{high:g}", str(int(inside.sum())),
                     f"{np.median(finite):.3f}" if finite.size else "–", f"{np.isfinite(ratio).mean():.0%}"])
    return rows


def window_summary(run: Run, max_lag: int) -> str:
    """Where the window τc stops measuring: the first frame it reads ``above`` K, with the truth there."""
    above = np.flatnonzero(run.window_status == WINDOW_ABOVE)
    measured = int((run.window_status == WINDOW_MEASURED).sum())
    if above.size == 0:
        return f"the window τc never read above K = {max_lag} ({measured} fits measured)"
    frame = int(run.window_frames[above[0]])
    truth = float(np.interp(frame, run.frames, run.truth)) if run.frames.size else math.nan
    share = float((run.window_status[above[0]:] == WINDOW_ABOVE).mean())
    return (f"the window τc reads above K = {max_lag} from frame {frame} on (truth there {truth:.0f} frames; "
            f"{share:.0%} of its fits from then on)")


def cost(size: int = 512, longest_age: int = 4096, per_octave: int = 4, repeats: int = 40,
         window: int = 128) -> dict[str, float]:
    """Seconds per frame over a size² region, interleaved in one run (the fastest of ``repeats``
    rounds each, so that other work on the machine inflates no ratio): one S1 push and the default
    push (S1, S2, S3; sliding window N = ``window``, m = 1, one thread), the kinetics' push (fused
    numba pass, and the NumPy path) and its measure, and both again keeping every SAMPLING-th pixel of
    the region in each direction (the box means still read every pixel), and on the frame itself
    subsampled so (the box means too); all per pixel of the size² region; memory per region pixel."""
    from edgedsm.estimators import SlidingWindow

    rng = np.random.default_rng(1)
    frames = [rng.integers(1, 250, (size, size), dtype=np.uint8) for _ in range(8)]
    mask, model = np.ones((size, size), bool), NoiseModel(gain=0.25, dark_variance=1.0)
    s1 = SlidingWindow((size, size), window=window, lag=1, estimators=("s1",), threads=1)
    default = SlidingWindow((size, size), window=window, lag=1, threads=1)
    fused = Kinetics(mask, model, longest_age, per_octave)
    numpy_path = Kinetics(mask, model, longest_age, per_octave, kernel="numpy")
    rows, cols = np.indices(mask.shape)
    sampled = Kinetics((rows % SAMPLING == 0) & (cols % SAMPLING == 0), model, longest_age, per_octave)
    coarse = Kinetics(np.ones(mask[::SAMPLING, ::SAMPLING].shape, bool), model, longest_age, per_octave)
    steps = {"s1": s1.push, "default": default.push, "push": fused.push, "push_numpy": numpy_path.push,
             "measure": lambda _frame: fused.measure(), "push_sampled": sampled.push,
             "measure_sampled": lambda _frame: sampled.measure(),
             "push_coarse": lambda frame: coarse.push(frame[::SAMPLING, ::SAMPLING]),
             "measure_coarse": lambda _frame: coarse.measure()}
    for index in range(window + 8):  # fill the windows and the young slots (and compile)
        for name, step in steps.items():
            if not name.startswith("measure"):
                step(frames[index % 8])
    best = dict.fromkeys(steps, math.inf)
    for index in range(repeats):
        for name, step in steps.items():
            start = time.perf_counter()
            step(frames[index % 8])
            best[name] = min(best[name], time.perf_counter() - start)
    out = dict(best)
    out.update(slots=float(slot_schedule(longest_age, per_octave)[0].size), pixels=float(size * size),
               bytes_per_pixel=fused.memory_bytes / (size * size), fused=float(fused._fused is not None))
    return out


def cost_rows(spent: dict[str, float]) -> list[list[str]]:
    names = {"s1": "S1 push", "default": "default push (S1, S2, S3)",
             "push": "kinetics push" + (" (numba)" if spent["fused"] else " (NumPy: numba missing)"),
             "push_numpy": "kinetics push, NumPy path", "measure": "kinetics measure",
             "push_sampled": f"kinetics push, every {SAMPLING}th pixel kept", "measure_sampled":
             f"kinetics measure, every {SAMPLING}th pixel kept",
             "push_coarse": f"kinetics push of frame[::{SAMPLING}, ::{SAMPLING}]",
             "measure_coarse": f"kinetics measure of frame[::{SAMPLING}, ::{SAMPLING}]"}
    return [[label, f"{1e9 * spent[key] / spent['pixels']:.2f}", f"{spent[key] / spent['s1']:.2f}",
             f"{spent[key] / spent['default']:.2f}"] for key, label in names.items()]


def draw(result: Result, path: Path) -> None:
    """τ(t) against the truth and the window τc (left), τ/truth of every variant (right)."""
    from edgedsm_lab.report.figures import figure_class

    case = result.case
    fig = figure_class()(figsize=(13, 4.8), layout="constrained")
    left, right = fig.subplots(1, 2)
    base = result.runs[case.variants[0]]
    film = scene_of(case, base.variant)
    law = np.array([case.tau_start * film.activity.drying.factor(int(t)) for t in base.frames])
    left.semilogy(base.frames, law, color="grey", linewidth=1, linestyle=":", label="the scene's τc(t)")
    left.semilogy(base.frames, base.truth, color="black", linewidth=2, label="truth: ∫dt/τc = 1")
    left.semilogy(base.frames, base.tau, ".", markersize=2, color="tab:blue", label="τ(t), kinetics")
    shown = base.window_status == WINDOW_MEASURED
    left.semilogy(base.window_frames[shown], base.window_tau[shown], "s", markersize=3, color="tab:red",
                  label=f"window τc (N={case.window}, K={case.max_lag})")
    above = base.window_status == WINDOW_ABOVE
    left.semilogy(base.window_frames[above], base.window_tau[above], "^", markersize=3, color="tab:red",
                  markerfacecolor="none", label="window τc: above K")
    left.axhline(case.longest_age, color="grey", linestyle="--", linewidth=1, label="longest age")
    left.set_xlabel("frame t")
    left.set_ylabel("decorrelation time (frames)")
    left.set_title(f"{base.variant}: τc {case.tau_start:g} → {case.tau_start * case.final_factor:g} frames, "
                   f"{case.size}², {case.per_octave}/octave", fontsize=10)
    left.legend(fontsize=8)
    for run in result.runs.values():
        inside = (run.truth >= 1.0) & (run.truth <= case.longest_age)
        right.semilogx(run.truth[inside], run.tau[inside] / run.truth[inside], ".", markersize=2, label=run.variant)
    for run in result.runs.values():
        if "phase noise" in run.variant:  # what measure(white=True) is for
            inside = (run.truth >= 1.0) & (run.truth <= case.longest_age)
            right.semilogx(run.truth[inside], run.tau_white[inside] / run.truth[inside], ".", markersize=2,
                           color="tab:brown", label=f"{run.variant}, white step out")
        if "beam" in run.variant:  # what the flattening is for
            inside = (run.truth >= 1.0) & (run.truth <= case.longest_age)
            right.semilogx(run.truth[inside], run.tau_plain[inside] / run.truth[inside], ".", markersize=2,
                           color="black", label=f"{run.variant}, Eq. 1 unflattened")
    right.axhspan(1 - TOLERANCE, 1 + TOLERANCE, color="grey", alpha=0.15)
    right.set_ylim(0.3, 2.0)
    right.set_xlabel("truth (frames)")
    right.set_ylabel("τ / truth")
    right.set_title("each effect alone (shaded: ±25 %)", fontsize=10)
    right.legend(fontsize=8, markerscale=4)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80, pil_kwargs={"optimize": True})


def report_lines(result: Result, report: Report) -> None:
    case = result.case
    rows = []
    for run in result.runs.values():
        for label, tau in (("kinetics", run.tau), ("Eq. 1 unflattened", run.tau_plain),
                           ("kinetics, white step out", run.tau_white)):
            s = score(run.truth, tau, case.longest_age)
            rows.append([run.variant, label, f"{s.median_error:.3f}", f"{s.median_ratio:.3f}", f"{s.share_ok:.0%}",
                         f"{s.truth_low:.1f}–{s.truth_high:.0f}", str(s.samples)])
    report.table(["film", "estimator", "median |τ/truth − 1|", "median τ/truth", "with a number",
                  "truth (frames)", "samples"], rows)
    report.line()
    for run in result.runs.values():
        report.line(f"**{run.variant}** ({run.seconds:.0f} s): {window_summary(run, case.max_lag)}; "
                    f"beyond the longest age: {_beyond(run, case.longest_age)}.")
        report.line()
        report.table(["truth (frames)", "samples", "median τ/truth", "with a number"],
                     decade_rows(run, case.longest_age))
        report.line()


def _beyond(run: Run, longest_age: int) -> str:
    beyond = run.truth > longest_age
    if not beyond.any():
        return "no sample"
    statuses = [status for status, out in zip(run.status, beyond, strict=True) if out]
    return f"{statuses.count('above') / len(statuses):.0%} of {len(statuses)} samples read `above`"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_output_argument(parser, "docs/kinetics-bench.md")
    parser.add_argument("--quick", action="store_true", help="32², 12,000 frames, the plain film only")
    parser.add_argument("--figure", default="", help="write the figure to this PNG")
    parser.add_argument("--cost-size", type=int, default=512, help="region side for the cost (default 512)")


def run(args: argparse.Namespace) -> int:
    load = load_average()
    case = QUICK if args.quick else Case()
    result = measure(case)
    report = Report("Drying kinetics over decades")
    report.line(report.machine("edgedsm bench kinetics" + (" --quick" if args.quick else ""),
                               load=load))
    report.line()
    report_lines(result, report)
    spent = cost(args.cost_size, case.longest_age, case.per_octave)
    report.line(f"Cost per frame at {args.cost_size}² ({spent['slots']:.0f} slots up to {case.longest_age} frames; "
                f"the fastest of 40 interleaved rounds):")
    report.line()
    report.table(["step", "ns per region pixel", "× one S1 push", "× the default push (S1, S2, S3)"],
                 cost_rows(spent))
    report.line()
    report.line(f"Memory: {spent['bytes_per_pixel']:.0f} bytes per region pixel ((slots + 1) × 4 bytes).")
    if args.figure:
        draw(result, Path(args.figure))
    if args.output:
        report.save(args.output)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=HELP)
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())


__all__ = ["QUICK", "VARIANTS", "Case", "Result", "Run", "Score", "cost", "draw", "measure", "run_variant",
           "scene_of", "score"]
