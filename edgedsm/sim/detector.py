"""The detector of the §2A model on camera rows: photons, their noises, range and quantization.

Photons N_ph = I·gain·level (gain fixed on frame 0, ``level`` the scene's light level at the
frame: darkening and exposure steps), then, each from its own stream: Poisson shot noise on
N_ph, ambient photons Poisson(η·N_max), thermal (dark-current) electrons Poisson(d); sums of
independent Poisson variables are Poisson with the summed mean, so this is the paper's
Poisson(N_ph + N_al) with a dark current added (EMVA 1288's linear camera model, electrons and
photons counted alike: quantum efficiency 1). The range N_max + sqrt(N_max) maps onto
0..2^bits-1, then rounded (quantization) and clipped (saturation).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from edgedsm.sim.poisson import ConstantPoisson, poisson
from edgedsm.sim.scene import Scene


class DetectorRows:
    """The detector of one scene (which must have a [detector] table)."""

    def __init__(self, scene: Scene) -> None:
        detector = scene.detector
        if detector is None:
            raise ValueError("the scene has no [detector] table")
        self.detector = detector
        self.effects = scene.active_effects
        ambient = scene.ambient_light
        levels = [0.0] if ambient is None else ambient.levels
        #: η·N_max photons for each η the run takes (one alias table each, built once)
        self.ambient_means = {eta: eta * detector.n_max for eta in levels}
        self.ambient: dict[float, ConstantPoisson] = {}
        if "ambient_light" in self.effects and detector.shot_noise:  # else: its mean, no noise
            self.ambient = {eta: ConstantPoisson(mean) for eta, mean in self.ambient_means.items() if mean > 0}
        self.dark = ConstantPoisson(detector.dark_current) if "dark_current" in self.effects else None
        self.top = 2**detector.bits - 1
        self.scale = self.top / (detector.n_max + math.sqrt(detector.n_max))  # grey levels per photon

    def rows(self, intensity: np.ndarray, photons_per_unit: float,
             stream: Callable[[str], np.random.Generator], out: np.ndarray, eta: float = 0.0) -> None:
        """Grey levels of ``intensity`` rows into ``out`` under ambient light ``eta`` (one of the
        scene's levels); ``stream(effect)`` is the block's sub-stream of that effect."""
        photons = intensity.astype(np.float64) * photons_per_unit
        if "shot_noise" in self.effects:
            photons = poisson(stream("shot_noise"), photons)
        if eta in self.ambient:
            photons += self.ambient[eta].draw(stream("ambient_light"), photons.shape)
        elif self.ambient_means.get(eta, 0.0):
            photons += self.ambient_means[eta]
        if self.dark is not None:
            photons += self.dark.draw(stream("dark_current"), photons.shape)
        grey = photons
        grey *= self.scale
        if self.detector.quantization:
            np.rint(grey, out=grey)
        np.clip(grey, 0, self.top, out=grey)
        np.copyto(out, grey, casting="unsafe")
