"""Reproduction of the paper's §2 noise analysis (Figs. 2-7) on simulated speckle.

Levchenko et al. 2022, "Noise analysis in outdoor dynamic speckle measurement"
(``paper/000_b92683b691ade727.txt``). :func:`reproduce` simulates the paper's two test objects
with :mod:`edgedsm.sim`, computes S1, S2, S3 (Eq. 1-4) with :mod:`edgedsm.estimators` and writes
``report.md`` (tables with the numbers), PNG figures and ``results.json`` into a directory:

- Fig. 2: constant activity (τc = 20 Δt): histograms of S1 (uniform light) and S2, S3
  (Gaussian light, Ω = 300 Δ) for the ground truth (GT) and noise cases 1-3, and half GT /
  half case-3 maps.
- Fig. 3: the logo object ("IOMT", "ETRI" at τc = 10 Δt on a τc = 50 Δt background), uniform
  light: β of S1 for α = 0, 0.1, 0.2, 0.3, 0.5 (τ_noise = Δt) and the maps.
- Fig. 4: the logo object under Gaussian light (Ω = 300 δ = 150 Δ): S2 against S3 for GT,
  α = 0.2 and α = 0.2 with η = 0.2.
- Figs. 5-7: β, S_l and S_b against τ_noise for S1 (uniform, α = 0.2), S2 (Gaussian, α = 0.2,
  η = 0 and 0.1) and S3 (Gaussian, α = 0.2).

The paper does not say unambiguously how its phase noise evolves in time, so three readings
are run side by side (``Optical.model``):

- ``white``: θ drawn afresh every frame, σ_noise = α·sqrt(Δt/τ_noise) (the paper's literal
  formula; the simulator's "white" model);
- ``ou``: Ornstein-Uhlenbeck noise of the same stationary σ_noise, correlated over τ_noise
  (the simulator's "ou" model);
- ``walk``: the noise accumulates like the process phase, a random walk with step
  α·sqrt(Δt/τ_noise) ("similarly to the phase change related to the observed process").
  The sum of two independent Gaussian random walks is one random walk with the summed step
  variance, so this reading is simulated exactly with the simulator's activity model and an
  effective 1/τc' = 1/τc + α²/τ_noise.

Every simulation is seeded. A noisy run and its ground truth share the surface and activity
streams (and the laser shot noise), so they differ only by the noise under study. Each optical
simulation is run once and detected at every ambient-light level it is needed for.

The steps live in small modules: :mod:`~edgedsm_lab.report.plan` (settings, optical runs, scenes),
:mod:`~edgedsm_lab.report.runs` (the simulations), :mod:`~edgedsm_lab.report.measures` (the numbers),
:mod:`~edgedsm_lab.report.figures`, :mod:`~edgedsm_lab.report.findings` (the paper's claims against
our numbers) and :mod:`~edgedsm_lab.report.markdown` (report.md).
"""


from __future__ import annotations

import json
import time
from dataclasses import asdict
from pathlib import Path

from edgedsm.errors import EdgedsmError
from edgedsm_lab.report.figures import draw_figures, figure_class
from edgedsm_lab.report.markdown import write_report
from edgedsm_lab.report.measures import analyse, logo_geometry
from edgedsm_lab.report.plan import Settings, logo_regions, plan_runs
from edgedsm_lab.report.runs import ProgressBar, ProgressFactory, run_plan

__all__ = ["ProgressBar", "ProgressFactory", "Settings", "plan_runs", "reproduce"]


def reproduce(output_dir: str | Path, size: int = 256, frames: int = 200, quick: bool = False,
              progress: ProgressFactory | None = None, seed: int = 1,
              repeats: int | None = None) -> Path:
    """Run the reproduction; write report.md, the PNG figures and results.json into
    ``output_dir`` (created if needed). Returns the path of report.md.

    ``size`` camera pixels, ``frames`` per simulation, ``seed`` the first seed and ``repeats``
    the number of seeds averaged in Figs. 3-7 (default 3; 1 when ``quick``). ``progress`` is
    called once with the number of frames to simulate and returns a bar (e.g. tqdm) updated
    per frame. The full size takes a few minutes on two cores, ``quick`` a few seconds.
    """
    settings = Settings.make(size=size, frames=frames, seed=seed, repeats=repeats, quick=quick)
    figure_class()  # fail before minutes of simulation, not after
    out_dir = Path(output_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise EdgedsmError(f"cannot create the output directory {out_dir}: {exc.strerror}") from None
    start = time.perf_counter()
    regions, source = logo_regions(settings)
    geo = logo_geometry(settings, regions)
    plan = plan_runs(settings)
    maps = run_plan(settings, plan, regions, progress)
    results = analyse(settings, maps, geo)
    figures = draw_figures(settings, maps, results, geo, out_dir)
    elapsed = time.perf_counter() - start
    document = {"settings": asdict(settings), "logo_geometry": source,
                "logo_fraction_object_grid": geo.logo_fraction_object,
                "optical_runs": len(plan), "seconds": elapsed, **results}
    (out_dir / "results.json").write_text(json.dumps(document, indent=1, ensure_ascii=False),
                                          encoding="utf-8")
    return write_report(settings, results, figures, geo, source, out_dir, elapsed, len(plan))
