"""Constant films for the kinetics benchmark (docs/kinetics.md): how the flattening's box side and
pushing a subsampled frame move τ on films whose τc does not change (the truth is then τc itself,
:func:`edgedsm.sim.activity.decorrelation_lags` of a scene without drying); and, given its folder,
the public glue series (docs/real-data.md): τ of each drying stage at its last frame.

    python -m edgedsm_lab.bench.kinetics_films [--glue Fevicol_drying_04.03.2022]
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import numpy as np

from edgedsm.estimators.correlation_time import tau_c_bounds
from edgedsm.estimators.kinetics import Kinetics
from edgedsm.estimators.noise import NoiseModel, from_frames
from edgedsm.frameio import open_frames
from edgedsm.sim import Simulator, scene_from_dict
from edgedsm.sim.detector import DetectorRows
from edgedsm_lab.bench.report import Report, load_average

TAUS = (5.0, 50.0)  # frames: a fast and a slow film
BOXES = (0, 5, 9, 15)  # flatten: 0 is Eq. 1 unflattened
STEPS = (1, 2, 4)  # frame[::step, ::step]


@dataclass(frozen=True)
class Films:
    """``frames`` frames per film, the first ``skip`` left out (the oldest ages fill), measured
    every ``stride``; boxes on ``box_size``² uniform films, subsampling on ``step_size``² films
    under a Gaussian beam of Ω = step_size/2."""

    frames: int = 2000
    skip: int = 600
    stride: int = 5
    box_size: int = 48
    step_size: int = 128
    longest_age: int = 512
    seed: int = 5


def _film(size: int, tau: float, seed: int, beam: bool):
    data = {"scene": {"size": size, "seed": seed}, "activity": {"tau_c": tau},
            "detector": {"n_max": 1000.0, "bits": 8}}
    if beam:
        data["illumination"] = {"kind": "gaussian", "omega": size / 2}
    return scene_from_dict(data)


def _medians(films: Films, size: int, tau: float, beam: bool, estimators: dict, view) -> dict:
    """Median τ/τc and the scatter (std/τc) of each estimator over one film."""
    scene = _film(size, tau, films.seed, beam)
    simulator = Simulator(scene)
    found: dict = {key: [] for key in estimators}
    for index in range(films.frames):
        frame = simulator.next_frame()
        for key, kinetics in estimators.items():
            kinetics.push(view(frame, key))
            if index >= films.skip and index % films.stride == 0:
                result = kinetics.measure()
                found[key].append(np.nan if result.tau is None else result.tau)
    return {key: (float(np.nanmedian(v)) / tau, float(np.nanstd(v)) / tau, float(np.isfinite(v).mean()))
            for key, v in found.items()}


def boxes(films: Films, tau: float) -> dict:
    """Uniform light: median τ/τc per box side."""
    size = films.box_size
    model = NoiseModel(gain=DetectorRows(_film(size, tau, films.seed, False)).scale)
    estimators = {box: Kinetics(np.ones((size, size), bool), model, films.longest_age, flatten=box) for box in BOXES}
    return _medians(films, size, tau, False, estimators, lambda frame, _box: frame)


def steps(films: Films, tau: float) -> dict:
    """Gaussian beam: median τ/τc per subsampling step of the frame (the default box)."""
    size = films.step_size
    model = NoiseModel(gain=DetectorRows(_film(size, tau, films.seed, True)).scale)
    estimators = {step: Kinetics(np.ones((-(-size // step),) * 2, bool), model, films.longest_age) for step in STEPS}
    return _medians(films, size, tau, True, estimators, lambda frame, step: frame[::step, ::step])


GLUE_STAGES = ("0hr", "10min", "15min", "20min")  # the series' folder names: 0, 10, 15, 20 minutes
GLUE_MODEL_STAGE = "10min"  # the noise model from these frames (the wet stage is too fast to separate)


def glue(paths: dict[str, str], channel: str | None = "red", max_lag: int = 64) -> list[list[str]]:
    """Per stage (name -> a frame source): the kinetics at the last frame (every age up to the
    series' length), the share of its frames from the 33rd on that read ``above``, and the window
    τc of all its frames (K = ``max_lag``); the noise model from the GLUE_MODEL_STAGE stage's frames
    (:func:`edgedsm.estimators.noise.from_frames`; one camera, one setting)."""
    stacks = {}
    for stage, path in paths.items():
        with open_frames(path, channel) as reader:
            stacks[stage] = np.stack(list(reader.frames()))
    model = from_frames(stacks[GLUE_MODEL_STAGE] if GLUE_MODEL_STAGE in stacks else next(iter(stacks.values())))
    rows = []
    for stage, stack in stacks.items():
        mask = np.ones(stack.shape[1:], bool)
        kinetics = Kinetics(mask, model, stack.shape[0] - 1)
        results = []
        for index, frame in enumerate(stack):
            kinetics.push(frame)
            if index >= 32:
                results.append(kinetics.measure())
        plain = Kinetics(mask, NoiseModel(gain=0.0, quantized=False), stack.shape[0] - 1)  # no noise taken out
        for frame in stack:
            plain.push(frame)
        window = tau_c_bounds(stack, max_lag, mask)
        rows.append([stage, str(stack.shape[0]), f"{stack.mean():.1f}", _told(results[-1]),
                     f"{sum(r.status == 'above' for r in results) / len(results):.0%}",
                     f"{float(window.tau):.1f}" + (" (above K)" if window.tau == max_lag else ""),
                     _told(plain.measure())])
    return rows


def _told(result) -> str:
    """τ with one decimal, or the status with its bound."""
    if result.tau is not None:
        return f"{result.tau:.1f}"
    return f"{result.status} {result.bound:g}" if result.bound else result.status


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--glue", default="", help="the glue series' folder (its stages' data1 folders are read)")
    args = parser.parse_args(argv)
    load = load_average()
    films = Films()
    report = Report("Kinetics on constant films")
    report.line(report.machine("python -m edgedsm_lab.bench.kinetics_films", load=load))
    report.line()
    rows = []
    for tau in TAUS:
        found = boxes(films, tau)
        rows.append([f"{tau:g}"] + [f"{found[box][0]:.3f} ± {found[box][1]:.3f}" for box in BOXES])
    report.line(f"Uniform light, {films.box_size}²: median τ/τc ± std/τc by box side (0: Eq. 1 unflattened)")
    report.line()
    report.table(["τc (frames)"] + [f"box {box}" for box in BOXES], rows)
    report.line()
    rows = []
    for tau in TAUS:
        found = steps(films, tau)
        rows.append([f"{tau:g}"] + [f"{found[step][0]:.3f} ± {found[step][1]:.3f}" for step in STEPS])
    report.line(f"Gaussian beam Ω = {films.step_size // 2} px, {films.step_size}²: frame[::s, ::s], box 9")
    report.line()
    report.table(["τc (frames)"] + [f"s = {step}" for step in STEPS], rows)
    if args.glue:
        report.line()
        report.line("Glue series (red channel, data1 of each stage): τ at the last frame (frames)")
        report.line()
        stages = {stage: f"{args.glue}/{stage}/data1" for stage in GLUE_STAGES}
        report.table(["stage", "frames", "mean (DN)", "τ, last frame", "frames 33.. reading above",
                      "window τc (K = 64)", "τ, noise-free model"], glue(stages))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
