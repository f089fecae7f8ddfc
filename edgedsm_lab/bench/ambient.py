"""Does the ambient correction of S2 earn its place? Plain S2, S2 with the dark level subtracted
and clipped (the old correction), S2 corrected for level and shot noise
(:func:`edgedsm.estimators.ambient.ambient_corrected_s2`), S3 and τc against the ground truth
(η = 0) on the paper's two-level logo object, uniform and Gaussian light, α = 0.

Measures per map: mean/GT (map mean over the same estimator's GT map mean), beam imprint (0 flat,
1 proportional to the beam, negative rising to the edge; Gaussian light only), β = (S_l - S_b)/S_l
and the 5x5-smoothed AUC of logo against background. τc is scored by its rate 1/τc (activity
rises with 1/τc, as with S1..S3). Speed is not measured here.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from edgedsm.estimators import all_maps, tau_c
from edgedsm.estimators.ambient import ambient_corrected_s2, dark_statistics, mean_square_difference
from edgedsm.sim import Simulator, scene_from_dict
from edgedsm_lab.bench.report import Report, add_output_argument, load_average
from edgedsm_lab.report.measures import Geometry, logo_geometry, logo_measures
from edgedsm_lab.report.plan import Optical, Settings, logo_regions, scene_dict

HELP = "ambient-light correction of S2 against GT: mean/GT, imprint, β, AUC per η (docs/ambient.md)"
ETAS = (0.0, 0.05, 0.1, 0.2, 0.3)
ESTIMATORS = ("S2 plain", "S2 dark-clipped", "S2 corrected", "S3", "τc")
DARK_FRAMES = 10  # the daemon's default dark_frames
DARK_SMOOTH = 7  # box over which the dark mean and variance are averaged
TAU_MAX_LAG = 20
FACTOR_SMOOTH = 7  # box over which Ī and E[(ΔI)²] are averaged for the correction factors


@dataclass(frozen=True)
class Case:
    """Image size, frames, lag and seed of one run of the benchmark."""

    size: int = 128
    frames: int = 200
    lag: int = 10
    seed: int = 1
    etas: tuple[float, ...] = ETAS
    lights: tuple[str, ...] = ("uniform", "gaussian")


@dataclass
class Result:
    """measures[light][eta][estimator] = {"mean_ratio", "imprint", "beta", "auc"}; clipped fractions."""

    case: Case
    measures: dict[str, dict[float, dict[str, dict[str, float]]]] = field(default_factory=dict)
    clipped: dict[str, dict[float, float]] = field(default_factory=dict)
    seconds: float = 0.0


def _maps(stack: np.ndarray, dark: np.ndarray, lag: int) -> tuple[dict[str, np.ndarray], float]:
    """Every estimator's map of one detected stack, and the fraction of values the old correction clips."""
    plain = all_maps(stack, lag)
    dark_mean, dark_var = dark_statistics(dark, DARK_SMOOTH)
    level = dark.mean(axis=0)  # the old correction: the raw dark mean, per pixel
    clipped_stack = np.subtract(stack, np.minimum(stack, np.rint(level).astype(stack.dtype)))
    clipped_fraction = float((stack <= np.rint(level)).mean()) if level.any() else 0.0
    corrected = ambient_corrected_s2(plain["s2"], stack.mean(axis=0, dtype=np.float64),
                                     mean_square_difference(stack, lag), dark_mean, dark_var,
                                     smooth=FACTOR_SMOOTH)
    rate = 1.0 / np.asarray(tau_c(stack, max_lag=TAU_MAX_LAG), dtype=np.float64)
    return {"S2 plain": plain["s2"], "S2 dark-clipped": all_maps(clipped_stack, lag)["s2"],
            "S2 corrected": corrected, "S3": plain["s3"], "τc": rate}, clipped_fraction


def _simulate(case: Case, settings: Settings, gaussian: bool,
              regions: list[dict[str, Any]]) -> dict[float, tuple[np.ndarray, np.ndarray]]:
    """One optical run detected at every η: (frames, dark frames) per η; same laser draw for all."""
    key = Optical.make("logos", gaussian, 0.0, case.seed)
    detectors = {eta: Simulator(scene_from_dict(scene_dict(settings, key, eta, regions), source="bench"))
                 for eta in case.etas}
    optics = detectors[case.etas[0]]
    stacks = {eta: np.empty((case.frames, case.size, case.size), optics.output_dtype) for eta in case.etas}
    for index in range(case.frames):
        intensity = optics.next_intensity()
        for eta, detector in detectors.items():
            stacks[eta][index] = detector.detect(intensity)
    zeros = np.zeros((case.size, case.size), np.float32)
    return {eta: (stacks[eta], np.stack([detectors[eta].detect(zeros, laser_on=False)
                                         for _ in range(DARK_FRAMES)])) for eta in case.etas}


def measure(case: Case) -> Result:
    """Simulate and score every estimator at every η and light."""
    start = time.perf_counter()
    settings = Settings(size=case.size, frames=case.frames, seed=case.seed, lag=case.lag)
    regions, _ = logo_regions(settings)
    geo: Geometry = logo_geometry(settings, regions)
    result = Result(case)
    for light in case.lights:
        gaussian = light == "gaussian"
        runs = _simulate(case, settings, gaussian, regions)
        maps = {eta: _maps(stack, dark, case.lag) for eta, (stack, dark) in runs.items()}
        gt = maps[0.0][0] if 0.0 in maps else maps[min(maps)][0]
        result.measures[light], result.clipped[light] = {}, {}
        for eta, (by_estimator, clipped) in maps.items():
            result.clipped[light][eta] = clipped
            result.measures[light][eta] = {}
            for name, values in by_estimator.items():
                m = logo_measures(values, geo, settings.omega_logos if gaussian else None)
                result.measures[light][eta][name] = {
                    "mean_ratio": float(values.mean() / gt[name].mean()), "imprint": m.get("imprint", np.nan),
                    "beta": m["beta"], "auc": m["auc_smooth"]}
    result.seconds = time.perf_counter() - start
    return result


def beats_plain(result: Result) -> dict[str, dict[float, bool]]:
    """Per light and η: does the corrected S2 beat plain S2 on all four measures (η = 0: no worse)?

    Closer to GT counts for mean/GT (|log ratio|), imprint and β (absolute difference); AUC higher."""
    verdict: dict[str, dict[float, bool]] = {}
    for light, by_eta in result.measures.items():
        gt = by_eta[0.0]["S2 plain"] if 0.0 in by_eta else None
        verdict[light] = {}
        for eta, row in by_eta.items():
            plain, corr = row["S2 plain"], row["S2 corrected"]
            tol = 1e-9 if eta == 0 else 0.0
            checks = [abs(np.log(corr["mean_ratio"])) <= abs(np.log(plain["mean_ratio"])) + tol]
            if gt is not None:
                for key in ("beta", "imprint"):
                    if np.isfinite(gt[key]):
                        checks.append(abs(corr[key] - gt[key]) <= abs(plain[key] - gt[key]) + tol)
            checks.append(corr["auc"] >= plain["auc"] - tol)
            verdict[light][eta] = all(checks)
    return verdict


def table_rows(result: Result) -> list[list[str]]:
    """Markdown rows: light, η, estimator, mean/GT, imprint, β, AUC."""
    rows = []
    for light, by_eta in result.measures.items():
        for eta, by_est in by_eta.items():
            for name in ESTIMATORS:
                m = by_est[name]
                imprint = "–" if not np.isfinite(m["imprint"]) else f"{m['imprint']:+.2f}"
                rows.append([light, f"{eta:g}", name, f"{m['mean_ratio']:.2f}", imprint,
                             f"{m['beta']:.3f}", f"{m['auc']:.3f}"])
    return rows


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_output_argument(parser, "docs/ambient-table.md")
    parser.add_argument("--quick", action="store_true", help="64² x 100 frames (about a minute)")
    parser.add_argument("--size", type=int, default=128, help="image size in camera pixels (default 128)")
    parser.add_argument("--frames", type=int, default=200, help="frames per window (default 200)")
    parser.add_argument("--seed", type=int, default=1, help="simulation seed (default 1)")


def case_from_args(args: argparse.Namespace) -> Case:
    if args.quick:
        return Case(size=64, frames=100, seed=args.seed)
    return Case(size=args.size, frames=args.frames, seed=args.seed)


def run(args: argparse.Namespace) -> int:
    load = load_average()
    case = case_from_args(args)
    result = measure(case)
    report = Report("Ambient correction of S2 against the ground truth")
    command = "edgedsm bench ambient" + (" --quick" if args.quick else "")
    report.line(report.machine(command, "scipy", load=load) + f" Logo object, {case.size}², N = "
                f"{case.frames}, m = {case.lag}, α = 0, seed {case.seed}; {DARK_FRAMES} dark frames, dark "
                f"mean and variance averaged over {DARK_SMOOTH}x{DARK_SMOOTH} px; τc with K = {TAU_MAX_LAG} "
                f"scored as 1/τc; {result.seconds:.0f} s.")
    report.line()
    report.table(["light", "η", "estimator", "mean/GT", "imprint", "β", "AUC (5x5)"], table_rows(result))
    report.line()
    verdict = beats_plain(result)
    for light, by_eta in verdict.items():
        clipped = ", ".join(f"{100 * result.clipped[light][e]:.1f} %" for e in by_eta)
        wins = ", ".join(f"η={e:g}: {'yes' if ok else 'no'}" for e, ok in by_eta.items())
        report.line(f"- {light}: corrected S2 beats plain S2 on all four — {wins}; "
                    f"values the old correction clips to 0: {clipped}.")
    if args.output:
        report.save(args.output)
    return 0
