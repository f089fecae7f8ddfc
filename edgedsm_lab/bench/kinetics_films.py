"""Constant films for the kinetics benchmark (docs/kinetics.md): how the flattening's box side and
pushing a subsampled frame move τ on films whose τc does not change (the truth is then τc itself,
:func:`edgedsm.sim.activity.decorrelation_lags` of a scene without drying).

    python -m edgedsm_lab.bench.kinetics_films
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import numpy as np

from edgedsm.estimators.kinetics import Kinetics
from edgedsm.estimators.noise import NoiseModel
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


def main(argv: list[str] | None = None) -> int:
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args(argv)
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
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
