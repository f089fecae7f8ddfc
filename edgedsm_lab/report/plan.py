"""What the reproduction simulates: its settings, the optical runs and their scenes (paper §2)."""

from __future__ import annotations

import tomllib
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from importlib import resources
from importlib.resources.abc import Traversable
from pathlib import Path
from typing import Any

from edgedsm.errors import EdgedsmError
from edgedsm.sim.defaults import DEFAULT_SCENE

PAPER_SIZE = 256  # Nx = Ny of the paper; geometry and Ω scale with size / PAPER_SIZE
PAPER_LOGO_FRACTION = 29490 / 262144  # logo points of the paper's 2Nx x 2Ny object grid
MODELS = ("white", "ou", "walk")
_GEOMETRY_KEYS = ("x", "y", "width", "height", "cx", "cy", "radius", "inner_radius", "outer_radius")


@dataclass(frozen=True)
class Settings:
    """Parameters of one reproduction (the paper's values unless ``quick``)."""

    size: int = 256
    frames: int = 200
    seed: int = 1
    repeats: int = 3
    quick: bool = False
    lag: int = 10
    n_max: float = 1000.0
    bits: int = 8
    q: float = 0.0
    speckle_size: float = 2.0
    tau_c_constant: float = 20.0
    tau_c_logo: float = 10.0
    tau_c_background: float = 50.0
    alpha_cases: float = 0.2
    eta_cases: float = 0.2
    eta_fig6: float = 0.1
    alphas: tuple[float, ...] = (0.0, 0.1, 0.2, 0.3, 0.5)
    tau_noises: tuple[float, ...] = (1.0, 2.0, 5.0, 10.0, 20.0, 50.0)
    models: tuple[str, ...] = MODELS
    fig3_models: tuple[str, ...] = ("white", "walk")

    @classmethod
    def make(cls, size: int = 256, frames: int = 200, seed: int = 1, repeats: int | None = None,
             quick: bool = False) -> Settings:
        """Validated settings. ``quick`` caps size at 96 px and frames at 100, runs fewer α and
        τ_noise values and one seed: a few seconds instead of minutes."""
        if quick:
            settings = cls(size=min(size, 96), frames=min(frames, 100), seed=seed,
                           repeats=1 if repeats is None else repeats, quick=True,
                           alphas=(0.0, 0.2, 0.5), tau_noises=(1.0, 5.0, 20.0))
        else:
            settings = cls(size=size, frames=frames, seed=seed,
                           repeats=3 if repeats is None else repeats)
        settings.validate()
        return settings

    def validate(self) -> None:
        """Raise EdgedsmError for settings the reproduction cannot run with."""
        if not 32 <= self.size <= 2048:
            raise EdgedsmError(f"size must be 32..2048 camera pixels, got {self.size}")
        if self.frames < 2 * self.lag + 1:
            raise EdgedsmError(f"frames must be >= {2 * self.lag + 1} for the lag of {self.lag} "
                               f"frames, got {self.frames}")
        if not 1 <= self.repeats <= 20:
            raise EdgedsmError(f"repeats must be 1..20, got {self.repeats}")
        if not 0 <= self.seed <= 2**62:
            raise EdgedsmError(f"seed must be 0..2**62, got {self.seed}")
        unknown = set(self.models) - set(MODELS)
        if unknown or "white" not in self.models or not set(self.fig3_models) <= set(self.models):
            raise EdgedsmError(f"phase-noise models must be among {MODELS} and include 'white'")

    @property
    def scale(self) -> float:
        return self.size / PAPER_SIZE

    @property
    def omega_constant(self) -> float:
        """Ω of Fig. 2: 300 Δ (camera pixels, §2B), scaled with the image size."""
        return 300.0 * self.scale

    @property
    def omega_logos(self) -> float:
        """Ω of Figs. 4, 6, 7: 300 δ = 150 Δ (§2C), scaled with the image size."""
        return 150.0 * self.scale

    @property
    def seeds(self) -> tuple[int, ...]:
        return tuple(self.seed + k for k in range(self.repeats))

    def command(self, output_dir: Path | str) -> str:
        """The command line that makes this reproduction."""
        parts = ["edgedsm reproduce", f"-o {output_dir}"]
        if self.quick:
            parts.append("--quick")
        parts += [f"--size {self.size}", f"--frames {self.frames}", f"--seed {self.seed}",
                  f"--repeats {self.repeats}"]
        return " ".join(parts)


@dataclass(frozen=True)
class Optical:
    """One optical simulation: everything but the ambient light, which only the detector sees."""

    obj: str  # "constant" | "logos"
    gaussian: bool
    alpha: float
    tau_noise: float
    model: str  # "white" | "ou" | "walk"
    seed: int

    @classmethod
    def make(cls, obj: str, gaussian: bool, alpha: float, seed: int, tau_noise: float = 1.0,
             model: str = "white") -> Optical:
        """Without phase noise, τ_noise and the model do not matter: one key for all."""
        if alpha == 0:
            tau_noise, model = 1.0, "white"
        return cls(obj, gaussian, float(alpha), float(tau_noise), model, int(seed))


# -- scenes -------------------------------------------------------------------------------------
LOGOS_RESOURCE = "data/config/scenes/logos.toml"  # package data (the example scene), the paper's logo object


def _logos_file() -> Traversable:
    return resources.files("edgedsm").joinpath(LOGOS_RESOURCE)


def logo_regions(settings: Settings) -> tuple[list[dict[str, Any]], str]:
    """The logo regions at ``settings.size`` with the paper's τc, and where the geometry came from.

    Geometry comes from the package's ``edgedsm/data/config/scenes/logos.toml`` (the example
    ``config/scenes/logos.toml``, shipped in the wheel), else from the built-in default scene; coordinates scale to
    the size.
    """
    regions: list[dict[str, Any]] = [dict(r) for r in DEFAULT_SCENE["activity"]["regions"]]
    file_size = float(DEFAULT_SCENE["scene"]["size"])
    source = "edgedsm.sim.defaults.DEFAULT_SCENE"
    logos = _logos_file()
    label = f"edgedsm/{LOGOS_RESOURCE}"
    try:
        data = tomllib.loads(logos.read_text(encoding="utf-8"))
        found = data.get("activity", {}).get("regions", [])
        if found:
            regions = [dict(r) for r in found]
            file_size = float(data.get("scene", {}).get("size", PAPER_SIZE))
            source = label
    except (OSError, tomllib.TOMLDecodeError, AttributeError) as exc:
        source = f"edgedsm.sim.defaults.DEFAULT_SCENE ({label}: {exc})"
    factor = settings.size / file_size
    for region in regions:
        for key in _GEOMETRY_KEYS:
            if key in region:
                region[key] = float(region[key]) * factor
        if region.get("shape") == "mask" and not Path(region["path"]).is_absolute():
            region["path"] = str(Path(str(logos)).parent / region["path"])
        region["tau_c"] = settings.tau_c_logo
    return regions, source


def _with_walk(tau_c: float, key: Optical) -> float:
    """τc' with 1/τc' = 1/τc + α²/τ_noise: the process walk plus a random-walk phase noise."""
    if key.model != "walk" or key.alpha == 0:
        return tau_c
    return 1.0 / (1.0 / tau_c + key.alpha**2 / key.tau_noise)


def scene_dict(settings: Settings, key: Optical, eta: float,
               regions: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Scene (the TOML layout of edgedsm.sim.scene) of one optical run detected at η."""
    data: dict[str, Any] = {
        "scene": {"size": settings.size, "frames": settings.frames, "seed": key.seed,
                  "speckle_size": settings.speckle_size},
        "detector": {"n_max": settings.n_max, "bits": settings.bits},
    }
    if key.obj == "logos":
        data["activity"] = {
            "tau_c": _with_walk(settings.tau_c_background, key),
            "regions": [dict(r, tau_c=_with_walk(float(r["tau_c"]), key)) for r in regions]}
    else:
        data["activity"] = {"tau_c": _with_walk(settings.tau_c_constant, key)}
    if key.gaussian:
        omega = settings.omega_logos if key.obj == "logos" else settings.omega_constant
        data["illumination"] = {"kind": "gaussian", "omega": omega}
    if key.alpha > 0 and key.model != "walk":
        data["phase_noise"] = {"alpha": key.alpha, "tau_noise": key.tau_noise, "model": key.model}
    if eta > 0:
        data["ambient_light"] = {"eta": eta}
    return data


# -- the plan and the simulations --------------------------------------------------------------

def plan_runs(settings: Settings) -> dict[Optical, set[float]]:
    """Every optical simulation the report needs, with the ambient levels η to detect it at."""
    plan: dict[Optical, set[float]] = defaultdict(set)
    s = settings
    fig2_models = [m for m in ("white", "walk") if m in s.models]
    for gaussian in (False, True):  # Fig. 2: GT and cases 1-3
        for model in fig2_models:
            for alpha in (0.0, s.alpha_cases):
                plan[Optical.make("constant", gaussian, alpha, s.seed, model=model)].update(
                    {0.0, s.eta_cases})
    for seed in s.seeds:
        for model in s.fig3_models:  # Fig. 3
            for alpha in s.alphas:
                plan[Optical.make("logos", False, alpha, seed, model=model)].add(0.0)
        for alpha in (0.0, s.alpha_cases):  # Fig. 4, and the α = 0 references of Figs. 6-7
            plan[Optical.make("logos", True, alpha, seed)].update({0.0, s.eta_cases, s.eta_fig6})
        for model in s.models:  # Figs. 5-7
            for tau in s.tau_noises:
                plan[Optical.make("logos", False, s.alpha_cases, seed, tau, model)].add(0.0)
                plan[Optical.make("logos", True, s.alpha_cases, seed, tau, model)].update(
                    {0.0, s.eta_fig6})
    return dict(plan)

def fig2_cases(settings: Settings) -> dict[str, tuple[float, float, str]]:
    """Case name -> (α, η, phase-noise model) for Fig. 2; the walk rows are our addition."""
    s = settings
    cases = {"GT": (0.0, 0.0, "white"), "case 1": (s.alpha_cases, 0.0, "white"),
             "case 2": (0.0, s.eta_cases, "white"), "case 3": (s.alpha_cases, s.eta_cases, "white")}
    if "walk" in s.models:
        cases["case 1 (walk)"] = (s.alpha_cases, 0.0, "walk")
        cases["case 3 (walk)"] = (s.alpha_cases, s.eta_cases, "walk")
    return cases


def sweep_series(settings: Settings) -> list[tuple[str, str, bool, float]]:
    """(name, estimator, Gaussian light?, η) of the β-versus-τ_noise series (Figs. 5-7)."""
    eta = settings.eta_fig6
    return [
        ("S1, uniform, η=0 (Fig. 5)", "s1", False, 0.0),
        ("S2, Gaussian, η=0 (Fig. 6 left)", "s2", True, 0.0),
        (f"S2, Gaussian, η={eta:g} (Fig. 6 right)", "s2", True, eta),
        ("S3, Gaussian, η=0 (Fig. 7)", "s3", True, 0.0),
        (f"S3, Gaussian, η={eta:g} (not in the paper)", "s3", True, eta),
    ]

def light_runs(settings: Settings) -> list[tuple[str, bool, float, float]]:
    """(label, Gaussian light?, α, η) of the β-by-estimator comparison (white noise, τ_noise = Δt)."""
    a, e1, e2 = settings.alpha_cases, settings.eta_fig6, settings.eta_cases
    return [("uniform, GT", False, 0.0, 0.0), (f"uniform, α={a:g}", False, a, 0.0),
            ("Gaussian, GT", True, 0.0, 0.0), (f"Gaussian, α={a:g}", True, a, 0.0),
            (f"Gaussian, α={a:g}, η={e1:g}", True, a, e1), (f"Gaussian, α={a:g}, η={e2:g}", True, a, e2)]


def fig4_runs(settings: Settings) -> list[tuple[str, float, float]]:
    """(label, α, η) of the three columns of Fig. 4."""
    a, e = settings.alpha_cases, settings.eta_cases
    return [("GT", 0.0, 0.0), (f"α={a:g}", a, 0.0), (f"α={a:g}, η={e:g}", a, e)]
