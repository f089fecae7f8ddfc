"""Dynamic speckle simulator following the paper's §2A model, one frame at a time.

Per frame i (0-based here; the paper counts from 1):

1. Object phase on the 2Nx x 2Ny grid (spacing δ = Δ/2): uniform on [0, 2π) at i = 0, then a
   random walk φ_i = φ_{i-1} + χ·sqrt(Δt/τc(k,l)), χ ~ N(0,1), so that the intensity
   correlation is ρ(τ) = exp(-τ/τc).
2. Environmental phase noise ψ (from i = 1 on), σ_noise = α·sqrt(Δt/τ_noise). The paper draws
   θ independently per frame ("white", the default here). Because it also speaks of a noise
   correlation radius, the "ou" model offers an Ornstein-Uhlenbeck process with stationary
   standard deviation σ_noise and correlation time τ_noise, for the β-versus-τ_noise study.
3. Field U_S = sqrt(I0)·exp(-j(φ + ψ)), imaged through a circular pupil:
   U_cam = IFT{H·FT{U_S}}, and |U_cam|² averaged over 2x2 grid points per camera pixel
   (the paper sums; the factor 4 is absorbed by the detector gain).
4. Detector (optional): photons N_ph = I·N_max/max(I of frame 0) — the gain is fixed once, as
   on a real camera, so frames stay comparable — Poisson shot noise on N_ph, ambient photons
   Poisson(η·N_max) drawn separately (the sum of independent Poisson variables is Poisson with
   the summed mean, so this is the paper's Poisson(N_ph + N_al) while keeping the ground-truth
   draws untouched), then the range N_max + sqrt(N_max) mapped onto 0..2^bits-1 and rounded.

Memory is constant in the number of frames: only the current phase is kept.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Literal

import numpy as np
import scipy.fft

from edgedsm.sim.activity import tau_c_map
from edgedsm.sim.optics import beam_amplitude, pupil_transfer
from edgedsm.sim.scene import Scene
from edgedsm.sim.streams import effect_stream

Precision = Literal["single", "double"]
_TWO_PI = 2.0 * math.pi
_REWRAP_EVERY = 256  # frames between phase re-wraps into [0, 2π) (keeps float32 phases exact)


class Simulator:
    """Stateful frame generator for one scene.

    ``precision`` "single" computes fields in complex64 (fast), "double" in complex128;
    ``workers`` is the FFT thread count.
    """

    def __init__(self, scene: Scene, precision: Precision = "single", workers: int = 1) -> None:
        if precision not in ("single", "double"):
            raise ValueError(f"precision must be 'single' or 'double', not {precision!r}")
        if workers < 1:
            raise ValueError("workers must be >= 1")
        self.scene = scene
        self.precision = precision
        self.workers = workers
        self.size = scene.scene.size
        self.grid = 2 * self.size
        self._real = np.float32 if precision == "single" else np.float64
        self._complex = np.complex64 if precision == "single" else np.complex128
        self.effects = scene.active_effects
        self.rngs = {name: effect_stream(scene.scene.seed, name) for name in
                     ("surface", "activity", "phase_noise", "shot_noise", "ambient_light")
                     if name in self.effects}
        self._step0 = np.sqrt(1.0 / tau_c_map(scene)).astype(self._real)  # sqrt(Δt/τc)
        self._amplitude = beam_amplitude(scene.illumination, self.grid, self._real)
        self._pupil = pupil_transfer(self.size, scene.scene.effective_speckle_size, self._real)
        self._noise_sigma = 0.0
        self._noise_decay = 0.0
        if "phase_noise" in self.effects:
            noise = scene.phase_noise
            self._noise_sigma = noise.alpha * math.sqrt(1.0 / noise.tau_noise)
            if noise.model == "ou":
                self._noise_decay = math.exp(-1.0 / noise.tau_noise)
        self._gain: float | None = None
        self.reset()

    def reset(self) -> None:
        """Back to frame 0 with fresh streams (the same seed gives the same frames)."""
        self.rngs = {name: effect_stream(self.scene.scene.seed, name) for name in self.rngs}
        self.frame_index = 0
        self._phase = np.empty((self.grid, self.grid), self._real)
        self._draw = np.empty_like(self._phase)
        self._noise: np.ndarray | None = None
        self._gain = None

    # -- stages -------------------------------------------------------------------------
    def _advance_phase(self) -> np.ndarray:
        """Object phase φ + ψ for the current frame index (radians, working precision)."""
        i = self.frame_index
        if i == 0:
            self.rngs["surface"].random(out=self._phase, dtype=self._real)
            self._phase *= _TWO_PI
            return self._phase
        draw = self._draw
        self.rngs["activity"].standard_normal(out=draw, dtype=self._real)
        draw *= self._step0
        drying = self.scene.activity.drying
        if drying is not None:
            draw *= self._real(1.0 / math.sqrt(drying.factor(i)))
        self._phase += draw
        if i % _REWRAP_EVERY == 0:
            np.remainder(self._phase, _TWO_PI, out=self._phase)
        if self._noise_sigma == 0.0:
            return self._phase
        rng = self.rngs["phase_noise"]
        if self._noise is None or self._noise_decay == 0.0:
            # white noise, or the first OU sample drawn from its stationary distribution
            self._noise = rng.standard_normal(size=draw.shape, dtype=self._real)
            self._noise *= self._real(self._noise_sigma)
        else:
            a = self._noise_decay
            rng.standard_normal(out=draw, dtype=self._real)
            self._noise *= self._real(a)
            self._noise += draw * self._real(self._noise_sigma * math.sqrt(1.0 - a * a))
        return self._phase + self._noise

    def _field(self, phase: np.ndarray) -> np.ndarray:
        """U_S = sqrt(I0)·exp(-jφ) on the object grid."""
        field = np.empty(phase.shape, self._complex)
        np.cos(phase, out=field.real)
        np.sin(phase, out=field.imag)
        np.negative(field.imag, out=field.imag)
        if self._amplitude is not None:
            field *= self._amplitude
        return field

    def _propagate(self, field: np.ndarray) -> np.ndarray:
        """|U_cam|² = |IFT{H·FT{U_S}}|² on the object grid (mean <I0>)."""
        spectrum = scipy.fft.fft2(field, workers=self.workers, overwrite_x=True)
        spectrum *= self._pupil
        camera = scipy.fft.ifft2(spectrum, workers=self.workers, overwrite_x=True)
        return camera.real**2 + camera.imag**2

    @staticmethod
    def _bin(grid_intensity: np.ndarray) -> np.ndarray:
        """Average over 2x2 grid points per camera pixel (pixel integration)."""
        g = grid_intensity
        out = g[0::2, 0::2] + g[1::2, 0::2]
        out += g[0::2, 1::2]
        out += g[1::2, 1::2]
        out *= 0.25
        return out

    # -- public -------------------------------------------------------------------------
    def next_grid_intensity(self) -> np.ndarray:
        """Advance one frame; |U_cam|² on the 2N grid, before pixel integration and detection."""
        grid = self._propagate(self._field(self._advance_phase()))
        self.frame_index += 1
        return grid

    def next_intensity(self) -> np.ndarray:
        """Advance one frame; irradiance per camera pixel in relative units (mean <I0>)."""
        return self._bin(self.next_grid_intensity())

    def detect(self, intensity: np.ndarray, laser_on: bool = True) -> np.ndarray:
        """Detector model (Poisson shot noise, ambient light, range, quantization).

        Without a [detector] table the intensity is returned unchanged. With the laser off the
        sensor sees the ambient light only.
        """
        detector = self.scene.detector
        if detector is None:
            return intensity if laser_on else np.zeros_like(intensity)
        if self._gain is None:
            peak = float(intensity.max())
            self._gain = detector.n_max / peak if peak > 0 else 0.0
        photons = intensity.astype(np.float64) * (self._gain if laser_on else 0.0)
        if "shot_noise" in self.effects:
            photons = self.rngs["shot_noise"].poisson(photons).astype(np.float64)
        if self.scene.ambient_light is not None:
            ambient = self.scene.ambient_light.eta * detector.n_max
            if "ambient_light" in self.effects and detector.shot_noise:
                photons += self.rngs["ambient_light"].poisson(ambient, size=photons.shape)
            else:
                photons += ambient
        top = 2**detector.bits - 1
        grey = photons * (top / (detector.n_max + math.sqrt(detector.n_max)))
        if not detector.quantization:
            return np.clip(grey, 0.0, top).astype(np.float32)
        np.rint(grey, out=grey)
        np.clip(grey, 0, top, out=grey)
        return grey.astype(np.uint8 if detector.bits <= 8 else np.uint16)

    def next_frame(self, laser_on: bool = True) -> np.ndarray:
        """Advance one frame and return what the camera delivers."""
        return self.detect(self.next_intensity(), laser_on)

    def frames(self, count: int | None = None) -> Iterator[np.ndarray]:
        """Yield ``count`` frames (default: the scene's ``frames``), one at a time."""
        total = self.scene.scene.frames if count is None else count
        for _ in range(total):
            yield self.next_frame()

    @property
    def output_dtype(self) -> np.dtype:
        detector = self.scene.detector
        if detector is None:
            return np.dtype(self._real)
        if not detector.quantization:
            return np.dtype(np.float32)
        return np.dtype(np.uint8 if detector.bits <= 8 else np.uint16)


def simulate(scene: Scene, precision: Precision = "single", workers: int = 1) -> Iterator[np.ndarray]:
    """Yield the scene's frames: uint8 (<= 8-bit detector), uint16 (wider), float without detector."""
    yield from Simulator(scene, precision=precision, workers=workers).frames()
