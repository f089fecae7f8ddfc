"""Scene files (TOML): which physical effects to simulate and with which parameters.

Every effect is an optional table; an absent table means the effect is not simulated at all
(no cost, no random numbers). Units: lengths in camera pixels (Δ) unless stated, times in
frame intervals (Δt), intensities in photons. See the paper's §2A; region shapes are
those of ``edgedsm.geometry`` (the daemon's regions use the same ones).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, model_validator

from edgedsm import geometry
from edgedsm.errors import ConfigError
from edgedsm.validation import StrictModel, read_toml, validate

TauC = Annotated[float, Field(gt=0.0, le=1e12, description="temporal correlation radius τc, in Δt")]


class Pupil(StrictModel):
    """Imaging optics; the mean speckle size on the sensor is λ·f/(D·Δ) pixels."""

    diameter_mm: float = Field(gt=0, le=1000, description="aperture diameter D of the objective, mm")
    focal_mm: float = Field(gt=0, le=10000, description="focal distance f of the objective, mm")
    wavelength_nm: float = Field(632.8, gt=100, le=20000, description="laser wavelength λ, nm")
    pixel_pitch_um: float = Field(3.45, gt=0, le=1000, description="camera pixel pitch Δ, µm")

    @property
    def speckle_size(self) -> float:
        """Mean speckle size λf/(DΔ) in camera pixels."""
        return (self.wavelength_nm * 1e-9 * self.focal_mm) / (self.diameter_mm * self.pixel_pitch_um * 1e-6)


class SceneSection(StrictModel):
    size: int = Field(256, ge=16, le=8192, description="camera pixels per side (Nx = Ny); object grid is 2*size")
    frames: int = Field(200, ge=1, le=100_000_000, description="number of frames simulate() yields")
    seed: int = Field(1, ge=0, le=2**63 - 1, description="master seed; each effect derives its own stream")
    speckle_size: float | None = Field(
        None, ge=0.5, le=256, description="mean speckle size λf/(DΔ) in camera pixels (default 2)")
    pupil: Pupil | None = Field(None, description="give the optics instead of speckle_size")
    dt: float = Field(1.0, gt=0, le=3600, description="frame interval Δt in seconds (pacing of the simulated camera)")

    @model_validator(mode="after")
    def _one_speckle_spec(self) -> SceneSection:
        if self.speckle_size is not None and self.pupil is not None:
            raise ValueError("give either speckle_size or pupil, not both")
        size = self.effective_speckle_size
        if size > self.size / 2:
            raise ValueError(f"speckle size {size:.3g} px is larger than half the image ({self.size} px)")
        return self

    @property
    def effective_speckle_size(self) -> float:
        if self.pupil is not None:
            return self.pupil.speckle_size
        return 2.0 if self.speckle_size is None else self.speckle_size


class SceneRegion(StrictModel):
    """What a scene region adds to its shape (``edgedsm.geometry``): its own τc and a label.
    Shapes are in camera pixels; a mask's path is relative to the scene file."""

    tau_c: TauC
    name: str = Field("", max_length=64, description="label used in reports")


class FullRegion(geometry.Full, SceneRegion):
    pass


class RectRegion(geometry.Rect, SceneRegion):
    pass


class CircleRegion(geometry.Circle, SceneRegion):
    pass


class RingRegion(geometry.Ring, SceneRegion):
    pass


class PolygonRegion(geometry.Polygon, SceneRegion):
    pass


class TextRegion(geometry.Text, SceneRegion):
    pass


class MaskRegion(geometry.Mask, SceneRegion):
    pass


Region = Annotated[
    FullRegion | RectRegion | CircleRegion | RingRegion | PolygonRegion | TextRegion | MaskRegion,
    Field(discriminator="shape"),
]


class Drying(StrictModel):
    """τc of the whole surface grows by ``final_factor`` over ``duration`` frames from ``start``."""

    law: Literal["exponential", "linear", "logistic"] = Field(
        "exponential", description="shape of the growth of τc over time")
    start: int = Field(0, ge=0, le=100_000_000, description="frame at which drying begins")
    duration: int = Field(gt=0, le=100_000_000, description="frames from start to the final τc")
    final_factor: float = Field(gt=1.0, le=1e9, description="τc at the end divided by τc at the start")

    def factor(self, frame: int) -> float:
        """Multiplier of τc at ``frame`` (1 before start, final_factor after start+duration)."""
        return law_factor(self.law, (frame - self.start) / self.duration, self.final_factor)


def law_factor(law: str, progress: float, final_factor: float) -> float:
    """A factor going from 1 (progress <= 0) to ``final_factor`` (progress >= 1) by ``law``."""
    progress = min(max(progress, 0.0), 1.0)
    if law == "exponential":
        return final_factor**progress
    if law == "linear":
        return 1.0 + (final_factor - 1.0) * progress
    # logistic in the log of the factor, normalised to pass through 1 and final_factor at the ends
    s = 1.0 / (1.0 + math.exp(-12.0 * (progress - 0.5)))
    s0, s1 = 1.0 / (1.0 + math.exp(6.0)), 1.0 / (1.0 + math.exp(-6.0))
    return final_factor ** ((s - s0) / (s1 - s0))


class Darkening(StrictModel):
    """The film's reflectance (the light reaching the camera) falls to ``final_factor`` of its
    start over ``duration`` frames from ``start``, as a drying film's does (same laws as drying)."""

    law: Literal["exponential", "linear", "logistic"] = Field(
        "exponential", description="shape of the fall of the reflectance over time")
    start: int = Field(0, ge=0, le=100_000_000, description="frame at which the darkening begins")
    duration: int = Field(gt=0, le=100_000_000, description="frames from start to the final reflectance")
    final_factor: float = Field(gt=0.0, lt=1.0, description="reflectance at the end divided by that at the start")

    def factor(self, frame: int) -> float:
        """Multiplier of the light at ``frame`` (1 before start, final_factor after start+duration)."""
        return law_factor(self.law, (frame - self.start) / self.duration, self.final_factor)


class ExposureStep(StrictModel):
    """From ``frame`` on, the light reaching the sensor is ``factor`` times the scene's start
    (an exposure-time or laser-power change; steps do not compound, the latest one holds)."""

    frame: int = Field(ge=0, le=100_000_000, description="first frame with this exposure")
    factor: float = Field(gt=0.0, le=1e3, description="light relative to the scene's start")


class Activity(StrictModel):
    tau_c: TauC = Field(description="τc of the background, in Δt")
    regions: list[Region] = Field(default_factory=list, max_length=256,
                                  description="areas with their own τc; later ones paint over earlier")
    drying: Drying | None = Field(None, description="optional growth of τc over time")


class Illumination(StrictModel):
    kind: Literal["uniform", "gaussian"] = Field("uniform", description="laser beam profile I0")
    omega: float = Field(300.0, gt=0, le=1e6, description="Gaussian width Ω in camera px (I0 = exp(-r²/Ω²))")


class PhaseNoise(StrictModel):
    """Environmental phase noise (vibration), σ_noise = α·sqrt(Δt/τ_noise), paper §2A."""

    alpha: float = Field(ge=0, le=10, description="α: noise spread relative to the process")
    tau_noise: float = Field(1.0, gt=0, le=1e9, description="correlation radius τ_noise of the noise, in Δt")
    model: Literal["white", "ou", "walk"] = Field(
        "white", description="white: fresh θ each frame (paper literal); ou: Ornstein-Uhlenbeck, "
                             "stationary std σ_noise, correlation time τ_noise; walk: a random walk "
                             "with step σ_noise, like the process phase")


def latest_at(frame: int, steps: Iterable[tuple[int, float]], start: float) -> float:
    """The value of the latest (first frame, value) step at or before ``frame`` (steps in
    increasing order of frame), else ``start``: what steps that do not compound give."""
    value = start
    for first, step_value in steps:
        if first > frame:
            break
        value = step_value
    return value


class AmbientStep(StrictModel):
    """From ``frame`` on, the ambient light is ``eta`` (a lamp or daylight switched on or off)."""

    frame: int = Field(ge=0, le=100_000_000, description="first frame with this ambient light")
    eta: float = Field(ge=0, le=100, description="η from this frame on: N_al = η·N_max photons per pixel")


class AmbientLight(StrictModel):
    eta: float = Field(ge=0, le=100, description="η: ambient photons per pixel N_al = η·N_max")
    steps: list[AmbientStep] = Field(default_factory=list, max_length=10_000,
                                     description="changes of η over the run, by frame (the latest one holds)")

    @model_validator(mode="after")
    def _ordered(self) -> AmbientLight:
        frames = [step.frame for step in self.steps]
        if frames != sorted(set(frames)):
            raise ValueError("ambient_light.steps must be in increasing order of frame, each frame once")
        return self

    def eta_at(self, frame: int) -> float:
        """η at ``frame``: the latest step's at or before it, else the scene's ``eta``."""
        return latest_at(frame, ((step.frame, step.eta) for step in self.steps), self.eta)

    @property
    def levels(self) -> list[float]:
        """Every η the run takes, in order of first use."""
        return list(dict.fromkeys([self.eta, *(step.eta for step in self.steps)]))


class Detector(StrictModel):
    n_max: float = Field(1000.0, gt=0, le=1e9, description="N_max: photons at the brightest pixel of frame 1")
    bits: int = Field(8, ge=1, le=16, description="bit depth of the digitised frames")
    shot_noise: bool = Field(True, description="Poisson photon noise on the laser signal")
    quantization: bool = Field(True, description="round to integer grey levels (else float grey levels)")
    dark_current: float = Field(0.0, ge=0, le=1e6, description="mean thermal electrons per pixel and frame "
                                "(Poisson, also with the laser off); 0: not simulated")


class Scene(StrictModel):
    scene: SceneSection = Field(default_factory=SceneSection)
    activity: Activity
    illumination: Illumination | None = None
    phase_noise: PhaseNoise | None = None
    ambient_light: AmbientLight | None = None
    detector: Detector | None = None
    darkening: Darkening | None = Field(None, description="the film's reflectance falling over time")
    exposure_steps: list[ExposureStep] = Field(default_factory=list, max_length=10_000,
                                               description="exposure or laser-power steps, by frame")
    base_dir: Path = Field(Path("."), exclude=True, description="directory relative paths resolve in")

    @model_validator(mode="after")
    def _consistent(self) -> Scene:
        if self.ambient_light is not None and self.detector is None:
            raise ValueError("ambient_light needs a [detector] table (N_al = eta * n_max photons)")
        if (self.darkening is not None or self.exposure_steps) and self.detector is None:
            raise ValueError("darkening and exposure_steps need a [detector] table (they scale its photons)")
        frames = [step.frame for step in self.exposure_steps]
        if frames != sorted(set(frames)):
            raise ValueError("exposure_steps must be in increasing order of frame, each frame once")
        return self

    def light_level(self, frame: int) -> float:
        """The light reaching the sensor at ``frame`` relative to frame 0's scale (darkening and
        exposure steps; 1.0 when the scene has neither)."""
        exposure = latest_at(frame, ((step.frame, step.factor) for step in self.exposure_steps), 1.0)
        return exposure * (1.0 if self.darkening is None else self.darkening.factor(frame))

    @property
    def shape(self) -> tuple[int, int]:
        return (self.scene.size, self.scene.size)

    @property
    def active_effects(self) -> tuple[str, ...]:
        """Effects that cost time and draw random numbers in this scene."""
        effects = ["surface", "activity"]
        if self.illumination is not None and self.illumination.kind != "uniform":
            effects.append("illumination")
        if self.phase_noise is not None and self.phase_noise.alpha > 0:
            effects.append("phase_noise")
        if self.detector is not None:
            effects.append("detector")
            if self.detector.shot_noise:
                effects.append("shot_noise")
            if self.ambient_light is not None and max(self.ambient_light.levels) > 0:
                effects.append("ambient_light")
            if self.detector.dark_current > 0:
                effects.append("dark_current")
            if self.darkening is not None:
                effects.append("darkening")
            if self.exposure_steps:
                effects.append("exposure_steps")
        return tuple(effects)


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene TOML file; ConfigError names the key path of every problem."""
    path = Path(path)
    data = read_toml(path)
    scene = validate(Scene, data, str(path))
    scene.base_dir = path.resolve().parent
    return scene


def scene_from_dict(data: dict, source: str = "<scene>") -> Scene:
    """Validate a scene given as a dict (the same layout as the TOML file)."""
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: a scene must be a table")
    return validate(Scene, data, source)
