"""The report's PNG figures (Figs. 2-7), drawn with matplotlib's object API (no pyplot state)."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from edgedsm.analysis import contrast
from edgedsm.errors import EdgedsmError
from edgedsm_lab.report.measures import Geometry, radial_profile
from edgedsm_lab.report.plan import Optical, Settings, fig2_cases, fig4_runs, sweep_series
from edgedsm_lab.report.runs import MapStore


def figure_class() -> Any:
    """matplotlib's Figure (Agg, no pyplot state), or a clear error when it is missing."""
    try:
        from matplotlib.figure import Figure
    except ImportError as exc:  # pragma: no cover - depends on the installation
        raise EdgedsmError("the reproduction report draws its figures with matplotlib, which is "
                           "not installed: pip install 'edgedsm[report]'") from exc
    return Figure


def _save(fig: Any, path: Path) -> str:
    fig.savefig(path, dpi=80, pil_kwargs={"optimize": True})
    return path.name


def _map_range(arrays: Iterable[np.ndarray]) -> tuple[float, float]:
    data = np.concatenate([np.ravel(a) for a in arrays])
    low, high = np.percentile(data, [1, 99])
    return float(low), float(high)


def _show(fig: Any, ax: Any, values: np.ndarray, vmin: float, vmax: float, title: str) -> None:
    image = ax.imshow(values, cmap="jet", vmin=vmin, vmax=vmax, interpolation="nearest")
    ax.set_title(title, fontsize=9)
    ax.tick_params(labelsize=7)
    fig.colorbar(image, ax=ax, fraction=0.046, pad=0.03).ax.tick_params(labelsize=7)


def draw_figures(settings: Settings, maps: MapStore, results: dict[str, Any], geo: Geometry,
                 output_dir: Path) -> dict[str, str]:
    """Write the PNG figures into ``output_dir``; returns {figure id: file name}."""
    Figure = figure_class()
    s = settings
    names: dict[str, str] = {}
    half = s.size // 2
    panels = (("s1", False, "S1, uniform"), ("s2", True, "S2, Gaussian"), ("s3", True, "S3, Gaussian"))
    cases = {k: v for k, v in fig2_cases(s).items() if "walk" not in k}

    fig = Figure(figsize=(12, 3.4), layout="constrained")
    axes = fig.subplots(1, 3)
    for ax, (est, gaussian, title) in zip(axes, panels, strict=True):
        data = {case: maps[(Optical.make("constant", gaussian, a, s.seed, model=m), e)][est]
                for case, (a, e, m) in cases.items()}
        low, high = _map_range(data.values())
        span = high - low
        bins = np.linspace(low - 0.15 * span, high + 0.15 * span, 80)
        for case, values in data.items():
            density, edges = np.histogram(values, bins=bins, density=True)
            ax.step(edges[:-1], density, where="post", label=case, linewidth=1.2)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel(est.upper())
        ax.set_ylabel("probability density")
        ax.legend(fontsize=8)
    fig.suptitle(f"Fig. 2 (left): constant activity τc={s.tau_c_constant:g}Δt, N={s.frames}, "
                 f"m={s.lag}; case 1 α={s.alpha_cases:g}, case 2 η={s.eta_cases:g}, case 3 both; "
                 "τ_noise=Δt (white)", fontsize=10)
    names["fig2_histograms"] = _save(fig, output_dir / "fig2_histograms.png")

    fig = Figure(figsize=(15, 3.6), layout="constrained")
    axes = fig.subplots(1, 4)
    for ax, (est, gaussian, title) in zip(axes, panels, strict=False):
        gt = maps[(Optical.make("constant", gaussian, 0.0, s.seed), 0.0)][est]
        noisy = maps[(Optical.make("constant", gaussian, s.alpha_cases, s.seed), s.eta_cases)][est]
        combined = np.concatenate([gt[:, :half], noisy[:, half:]], axis=1)
        low, high = _map_range([combined])
        _show(fig, ax, combined, low, high, f"{title}: GT | case 3")
        ax.axvline(half - 0.5, color="white", linewidth=0.8)
    ax = axes[3]
    for est in ("s2", "s3"):
        for case, alpha, eta, line in (("GT", 0.0, 0.0, "-"), ("case 3", s.alpha_cases, s.eta_cases, "--")):
            values = maps[(Optical.make("constant", True, alpha, s.seed), eta)][est]
            radius, profile = radial_profile(values, geo)
            ax.plot(radius, profile, line, label=f"{est.upper()} {case}")
    radius, profile = radial_profile(geo.beam(s.omega_constant), geo)
    ax.plot(radius, profile, "k:", label="beam I0")
    ax.set_title("radial profiles (Gaussian light), / centre", fontsize=9)
    ax.set_xlabel("distance from the beam axis (px)")
    ax.legend(fontsize=7)
    fig.suptitle("Fig. 2 (right): left half ground truth, right half noise case 3, one scale per map; "
                 "right: map means against radius", fontsize=10)
    names["fig2_maps"] = _save(fig, output_dir / "fig2_maps.png")

    rows = len(s.fig3_models)
    fig = Figure(figsize=(2.7 * len(s.alphas) + 0.4, 2.6 * rows + 0.4), layout="constrained")
    axes = np.array(fig.subplots(rows, len(s.alphas), squeeze=False))
    data = {(m, a): maps[(Optical.make("logos", False, a, s.seed, model=m), 0.0)]["s1"]
            for m in s.fig3_models for a in s.alphas}
    low, high = _map_range(data.values())
    for row, model in enumerate(s.fig3_models):
        for col, alpha in enumerate(s.alphas):
            values = data[(model, alpha)]
            beta = contrast(values, geo.logos, geo.background)
            _show(fig, axes[row, col], values, low, high, f"{model}  α={alpha:g}  β={beta:.3f}")
    fig.suptitle("Fig. 3: S1 of the logo object, uniform light, τ_noise=Δt, one scale\nrows: "
                 "phase-noise reading (white = the paper's formula, walk = accumulating noise)",
                 fontsize=10)
    names["fig3_maps"] = _save(fig, output_dir / "fig3_maps.png")

    fig = Figure(figsize=(13, 6.2), layout="constrained")
    axes = fig.subplots(2, 4)
    runs = fig4_runs(s)
    for row, est in enumerate(("s2", "s3")):
        data4 = [maps[(Optical.make("logos", True, a, s.seed), e)][est] for _, a, e in runs]
        low, high = _map_range(data4)
        for col, ((label, _, _), values) in enumerate(zip(runs, data4, strict=True)):
            beta = contrast(values, geo.logos, geo.background)
            _show(fig, axes[row, col], values, low, high, f"{est.upper()}  {label}  β={beta:.3f}")
            radius, profile = radial_profile(values, geo, within=geo.background)
            axes[row, 3].plot(radius, profile, label=label)
        radius, profile = radial_profile(geo.beam(s.omega_logos), geo)
        axes[row, 3].plot(radius, profile, "k:", label="beam I0")
        axes[row, 3].set_title(f"{est.upper()} background / centre, against radius", fontsize=9)
        axes[row, 3].set_xlabel("distance from the beam axis (px)")
        axes[row, 3].legend(fontsize=7)
    fig.suptitle(f"Fig. 4: logo object, Gaussian light Ω={s.omega_logos:g} px, τ_noise=Δt (white); "
                 "one scale per row; right: radial profiles of the background", fontsize=10)
    names["fig4_maps"] = _save(fig, output_dir / "fig4_maps.png")

    series = sweep_series(s)
    fig = Figure(figsize=(3.3 * len(series), 6.2), layout="constrained")
    axes = fig.subplots(2, len(series))
    taus = np.array(s.tau_noises)
    styles = {"white": ("-", "o", "C0"), "ou": ("--", "s", "C1"), "walk": (":", "^", "C2")}
    for col, (name, _, _, _) in enumerate(series):
        entry = results["sweep"][name]
        ax_beta, ax_mean = axes[0, col], axes[1, col]
        for model, points in entry["models"].items():
            line, marker, color = styles[model]
            for ax, key, label, fill in ((ax_beta, "beta", "β", color), (ax_mean, "s_l", "S_l", color),
                                         (ax_mean, "s_b", "S_b", "none")):
                mean = np.array([np.mean(points[str(t)][key]) for t in s.tau_noises])
                err = np.array([np.std(points[str(t)][key]) for t in s.tau_noises])
                ax.errorbar(taus, mean, yerr=err if s.repeats > 1 else None, linestyle=line,
                            marker=marker, markersize=4, capsize=2, color=color,
                            markerfacecolor=fill, label=f"{label} {model}")
        ax_beta.axhline(np.mean(entry["gt"]["beta"]), color="k", linestyle="-.", linewidth=0.8,
                        label="β GT")
        if entry["eta"] > 0:
            ax_beta.axhline(np.mean(entry["no_phase_noise"]["beta"]), color="grey",
                            linestyle="-.", linewidth=0.8, label=f"β α=0, η={entry['eta']:g}")
        for key in ("s_l", "s_b"):
            ax_mean.axhline(np.mean(entry["no_phase_noise"][key]), color="k", linestyle="-.",
                            linewidth=0.8)
        ax_beta.set_title(name, fontsize=9)
        for ax in (ax_beta, ax_mean):
            ax.set_xscale("log")
            ax.set_xlabel("τ_noise / Δt")
            ax.legend(fontsize=6)
        ax_beta.set_ylabel("β")
        ax_mean.set_ylabel("mean of the estimate")
    fig.suptitle(f"Figs. 5-7: logo object, α={s.alpha_cases:g}; dash-dot lines: no phase noise; "
                 f"bottom: S_l filled, S_b open markers; error bars: sd over {s.repeats} seed(s)",
                 fontsize=10)
    names["fig5_7_beta"] = _save(fig, output_dir / "fig5_7_beta.png")
    return names
