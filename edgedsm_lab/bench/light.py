"""What if the light changes during the run? A simulated film dries (τc from 2 to 200 frames)
under steady light, while darkening 10×, through an exposure step down or a laser-power step
up halfway, and under ambient light; each estimator, plain and above the camera's noise floor
(docs/noise.md), is read over disjoint windows of N frames from wet to dry.

Scores per estimator: the first (wet) and last (dry) window's value, their ratio, Spearman's ρ
of the values against time over all windows (−1: activity falls steadily as the film dries;
τc is scored by its rate 1/τc so that −1 is right for every row), and the above-noise verdict
of the last window. The noise model is the simulated camera's own datasheet (its gain, dark
current and 8 bits), so the floors are not fitted to the run.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass

import numpy as np
from scipy.stats import spearmanr

from edgedsm.estimators import all_maps, tau_c
from edgedsm.estimators.noise import from_datasheet
from edgedsm.estimators.noise_summary import region_noise
from edgedsm.sim import Simulator, scene_from_dict
from edgedsm_lab.bench.report import Report, add_output_argument, load_average

HELP = "estimators plain and above the noise floor while the light changes during a drying run (docs/accuracy.md)"
N_MAX = 16_000  # photons at full scale
DARK_CURRENT = 20.0  # e⁻ per frame
TAU_START, TAU_FACTOR = 2.0, 100.0
CONDITIONS = ("steady light", "film darkens 10×", "exposure ×0.3 halfway", "laser power ×3 halfway",
              "ambient light η = 0.3")
ESTIMATORS = ("S1", "S2", "S3", "τc (as 1/τc)", "S1 above noise", "S2 above noise", "S3 above noise")


@dataclass(frozen=True)
class Case:
    size: int = 64
    frames: int = 1200
    window: int = 100
    lag: int = 5
    seed: int = 11


def scene(case: Case, condition: str) -> dict[str, object]:
    """The drying film's scene dict under one of CONDITIONS: the film dries (and darkens) from
    frame 100 to 100 frames before the end; the steps come halfway."""
    drying = {"law": "exponential", "start": 100, "duration": case.frames - 200}
    light: dict[str, object] = {
        "steady light": {},
        "film darkens 10×": {"darkening": {**drying, "final_factor": 0.1}},
        "exposure ×0.3 halfway": {"exposure_steps": [{"frame": case.frames // 2, "factor": 0.3}]},
        "laser power ×3 halfway": {"exposure_steps": [{"frame": case.frames // 2, "factor": 3.0}]},
        "ambient light η = 0.3": {"ambient_light": {"eta": 0.3}},
    }[condition]
    return {"scene": {"size": case.size, "frames": case.frames, "seed": case.seed, "speckle_size": 2.0},
            "activity": {"tau_c": TAU_START, "drying": {**drying, "final_factor": TAU_FACTOR}},
            "detector": {"n_max": N_MAX, "bits": 8, "dark_current": DARK_CURRENT}, **light}


def camera_model():
    """The simulated detector's datasheet: full scale N_max + √N_max photons at 255 DN, Poisson
    dark current (its mean is an offset, its σ dark noise)."""
    gain = 255.0 / (N_MAX + np.sqrt(N_MAX))
    return from_datasheet(gain, float(np.sqrt(DARK_CURRENT)), dark_mean=gain * DARK_CURRENT)


def window_values(stack: np.ndarray, lag: int) -> dict[str, tuple[float, str | None]]:
    """Every estimator's whole-frame value over one window, with the above-noise verdict."""
    maps = all_maps(stack, lag)
    model = camera_model()
    values: dict[str, tuple[float, str | None]] = {}
    for name in ("s1", "s2", "s3"):
        summary = region_noise(stack, maps[name], name, lag, q=0.0 if name != "s2" else 1.0, model=model, bits=8)
        values[name.upper()] = (summary.estimate, None)
        values[f"{name.upper()} above noise"] = (float(summary.above_noise), summary.verdict)
    max_lag = max(2, min(stack.shape[0] // 2, stack.shape[0] - 2))
    values["τc (as 1/τc)"] = (1.0 / float(np.median(np.asarray(tau_c(stack, max_lag=max_lag)))), None)
    return values


def measure(case: Case) -> dict[str, dict[str, list[tuple[float, str | None]]]]:
    """condition -> estimator -> value per disjoint window, wet first."""
    out: dict[str, dict[str, list[tuple[float, str | None]]]] = {}
    for label in CONDITIONS:
        frames = np.stack(list(Simulator(scene_from_dict(scene(case, label), source="bench")).frames(case.frames)))
        per: dict[str, list[tuple[float, str | None]]] = {name: [] for name in ESTIMATORS}
        for start in range(0, case.frames - case.window + 1, case.window):
            for name, value in window_values(frames[start:start + case.window], case.lag).items():
                per[name].append(value)
        out[label] = per
    return out


def table_rows(result: dict[str, dict[str, list[tuple[float, str | None]]]]) -> list[list[str]]:
    rows = []
    for label, per in result.items():
        for name in ESTIMATORS:
            values = np.array([v for v, _ in per[name]])
            rho = spearmanr(np.arange(values.size), values).statistic
            ratio = values[-1] / values[0] if values[0] else float("nan")
            verdict = per[name][-1][1] or ""
            rows.append([label, name, f"{values[0]:.4g}", f"{values[-1]:.4g}", f"{ratio:.3f}", f"{rho:+.2f}",
                         verdict])
    return rows


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_output_argument(parser, "docs/accuracy-light.md")
    parser.add_argument("--quick", action="store_true", help="32², 600 frames, N = 50")
    parser.add_argument("--seed", type=int, default=11, help="simulation seed (default 11)")


def run(args: argparse.Namespace) -> int:
    load = load_average()
    case = Case(size=32, frames=600, window=50, seed=args.seed) if args.quick else Case(seed=args.seed)
    started = time.perf_counter()
    result = measure(case)
    report = Report("Estimators while the light changes during a drying run")
    command = "edgedsm bench light" + (" --quick" if args.quick else "")
    report.line(report.machine(command, "scipy", load=load) + f" A film drying (τc {TAU_START:g} → "
                f"{TAU_START * TAU_FACTOR:g} frames) at {case.size}², 8 bits, N_max = {N_MAX}, dark current "
                f"{DARK_CURRENT:g} e⁻/frame; disjoint windows of N = {case.window}, m = {case.lag}, whole frame; "
                f"noise model from the simulated camera's datasheet; {time.perf_counter() - started:.0f} s.")
    report.line()
    report.table(["light", "estimator", "wet", "dry", "dry/wet", "Spearman ρ", "dry verdict"], table_rows(result))
    report.line()
    report.line("ρ = −1: the value falls steadily from wet to dry; above 0: the light's change outweighs the "
                "drying. The verdict is the last window's above-noise verdict (low: within the noise).")
    if args.output:
        report.save(args.output)
    return 0
