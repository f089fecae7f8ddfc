"""Measures on the simulated maps (β, AUC, beam imprint, radial profiles) and the report's numbers."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy import ndimage, stats

from edgedsm.analysis import contrast, region_mean
from edgedsm.sim import region_masks, scene_from_dict, tau_c_map
from edgedsm_lab.report.plan import Optical, Settings, fig2_cases, fig4_runs, light_runs, scene_dict, sweep_series
from edgedsm_lab.report.runs import MapStore


@dataclass
class Geometry:
    """Logo masks and radial zones on the camera grid."""

    size: int
    logos: np.ndarray
    background: np.ndarray
    logo_fraction_object: float = 0.0
    radius: np.ndarray = field(init=False)
    centre: np.ndarray = field(init=False)
    periphery: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        coords = np.arange(self.size) + 0.25 - self.size / 2  # camera px from the beam axis
        self.radius = np.hypot(coords[:, None], coords[None, :])
        self.centre = self.radius < self.size / 4
        self.periphery = self.radius >= self.size / 2

    def beam(self, omega: float) -> np.ndarray:
        """I0 = exp(-r²/Ω²) on the camera grid."""
        return np.exp(-((self.radius / omega) ** 2))

    def imprint(self, values: np.ndarray, omega: float, within: np.ndarray | None = None) -> float:
        """How much of the beam profile a map shows: (1 - S_per/S_cen) / (1 - I0_per/I0_cen).

        S_cen and S_per are the map means at r < size/4 and at r >= size/2 (the corners):
        0 is a flat map, 1 a map proportional to I0, negative a map that rises to the edge.
        """
        centre = self.centre if within is None else self.centre & within
        periphery = self.periphery if within is None else self.periphery & within
        beam = self.beam(omega)
        map_ratio = region_mean(values, periphery) / region_mean(values, centre)
        beam_ratio = region_mean(beam, periphery) / region_mean(beam, centre)
        return (1.0 - map_ratio) / (1.0 - beam_ratio)


def logo_geometry(settings: Settings, regions: Sequence[dict[str, Any]]) -> Geometry:
    """Masks of the logo object at ``settings.size`` (from edgedsm.sim.region_masks)."""
    scene = scene_from_dict(scene_dict(settings, Optical.make("logos", False, 0.0, settings.seed),
                                       0.0, regions), source="logo object")
    masks = region_masks(scene)
    fraction = float((tau_c_map(scene) == settings.tau_c_logo).mean())
    return Geometry(settings.size, masks["regions"], masks["background"], fraction)


def auc(values: np.ndarray, active: np.ndarray, background: np.ndarray) -> float:
    """Probability that a random active pixel reads higher than a random background pixel."""
    a = values[active].astype(np.float64)
    b = values[background].astype(np.float64)
    ranks = stats.rankdata(np.concatenate([a, b]))
    return float((ranks[: a.size].sum() - a.size * (a.size + 1) / 2) / (a.size * b.size))


def smooth(values: np.ndarray, width: int = 5) -> np.ndarray:
    """Moving average over width x width pixels (the paper's optional smoothing of maps)."""
    return ndimage.uniform_filter(values.astype(np.float64), size=width, mode="nearest")


def radial_profile(values: np.ndarray, geo: Geometry,
                   within: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Mean of a map in rings around the beam axis, divided by its mean at r < size/4.

    Returns (ring centres in px, normalised means); rings are size/32 wide, empty ones dropped.
    """
    select = np.ones(values.shape, bool) if within is None else within
    width = geo.size / 32
    ring = np.floor(geo.radius / width).astype(int)
    centre = region_mean(values, geo.centre & select)
    radii, means = [], []
    for index in range(int(ring.max()) + 1):
        mask = (ring == index) & select
        if mask.sum() >= 20:
            radii.append((index + 0.5) * width)
            means.append(region_mean(values, mask) / centre)
    return np.array(radii), np.array(means)


def logo_measures(values: np.ndarray, geo: Geometry, omega: float | None = None) -> dict[str, float]:
    """β = (S_l - S_b)/S_l, S_l, S_b, visibility (AUC raw and 5x5-smoothed), beam imprint."""
    out = {
        "beta": contrast(values, geo.logos, geo.background),
        "s_l": region_mean(values, geo.logos),
        "s_b": region_mean(values, geo.background),
        "auc": auc(values, geo.logos, geo.background),
        "auc_smooth": auc(smooth(values), geo.logos, geo.background),
    }
    if omega is not None:
        out["imprint"] = geo.imprint(values, omega, within=geo.background)
    return out


def _aggregate(samples: list[dict[str, float]]) -> dict[str, list[float]]:
    """Per-seed measures -> {measure: [value per seed]}."""
    return {k: [float(s[k]) for s in samples] for k in samples[0]}

def analyse(settings: Settings, maps: MapStore, geo: Geometry) -> dict[str, Any]:
    """All numbers of the report (plain Python types, JSON-ready)."""
    s = settings
    fig2: dict[str, Any] = {}
    for light, gaussian in (("uniform", False), ("gaussian", True)):
        fig2[light] = {}
        gt_maps = maps[(Optical.make("constant", gaussian, 0.0, s.seed), 0.0)]
        for case, (alpha, eta, model) in fig2_cases(s).items():
            m = maps[(Optical.make("constant", gaussian, alpha, s.seed, model=model), eta)]
            fig2[light][case] = {}
            for est in ("s1", "s2", "s3"):
                values = m[est].astype(np.float64)
                gt = gt_maps[est].astype(np.float64)
                entry = {"mean": float(values.mean()), "std": float(values.std()),
                         "mean_ratio": float(values.mean() / gt.mean()),
                         "std_ratio": float(values.std() / gt.std()),
                         "w1": float(stats.wasserstein_distance(values.ravel(), gt.ravel())
                                     / gt.std())}
                if gaussian:
                    entry["imprint"] = geo.imprint(values, s.omega_constant)
                fig2[light][case][est] = entry

    fig3: dict[str, Any] = {}
    for model in s.fig3_models:
        fig3[model] = {str(alpha): _aggregate([
            logo_measures(maps[(Optical.make("logos", False, alpha, seed, model=model), 0.0)]["s1"],
                          geo) for seed in s.seeds]) for alpha in s.alphas}

    fig4: dict[str, Any] = {}
    for label, alpha, eta in fig4_runs(s):
        fig4[label] = {est: _aggregate([
            logo_measures(maps[(Optical.make("logos", True, alpha, seed), eta)][est], geo,
                          s.omega_logos) for seed in s.seeds]) for est in ("s2", "s3")}

    sweep: dict[str, Any] = {}
    for name, est, gaussian, eta in sweep_series(s):
        omega = s.omega_logos if gaussian else None

        def measure(key: Optical, eta: float = eta, est: str = est,
                    omega: float | None = omega) -> dict[str, float]:
            return logo_measures(maps[(key, eta)][est], geo, omega)

        entry: dict[str, Any] = {"estimator": est, "gaussian": gaussian, "eta": eta}
        entry["gt"] = _aggregate([logo_measures(
            maps[(Optical.make("logos", gaussian, 0.0, seed), 0.0)][est], geo, omega)
            for seed in s.seeds])
        entry["no_phase_noise"] = _aggregate([
            measure(Optical.make("logos", gaussian, 0.0, seed)) for seed in s.seeds])
        entry["models"] = {model: {str(tau): _aggregate([
            measure(Optical.make("logos", gaussian, s.alpha_cases, seed, tau, model))
            for seed in s.seeds]) for tau in s.tau_noises} for model in s.models}
        sweep[name] = entry
    photons_per_grey = (s.n_max + np.sqrt(s.n_max)) / (2**s.bits - 1)
    uniform_mean = maps[(Optical.make("constant", False, 0.0, s.seed), 0.0)]["mean"]
    gaussian_mean = maps[(Optical.make("logos", True, 0.0, s.seed), 0.0)]["mean"]
    signal = {
        "uniform_photons": float(uniform_mean.mean() * photons_per_grey),
        "logos_gaussian_centre_photons": region_mean(gaussian_mean, geo.centre) * photons_per_grey,
        "logos_gaussian_corner_photons": region_mean(gaussian_mean, geo.periphery) * photons_per_grey,
    }
    by_light: dict[str, Any] = {}
    for label, gaussian, alpha, eta in light_runs(s):
        by_light[label] = {est: _aggregate([logo_measures(
            maps[(Optical.make("logos", gaussian, alpha, seed), eta)][est], geo)
            for seed in s.seeds]) for est in ("s1", "s2", "s3")}
    return {"fig2": fig2, "fig3": fig3, "fig4": fig4, "sweep": sweep, "by_light": by_light,
            "signal": signal}
