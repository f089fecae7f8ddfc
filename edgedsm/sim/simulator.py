"""Dynamic speckle simulator following the paper's §2A model, one frame at a time.

Per frame i (0-based here; the paper counts from 1):

1. Object phase on the 2Nx x 2Ny grid (spacing δ = Δ/2): uniform on [0, 2π) at i = 0, then a
   random walk φ_i = φ_{i-1} + χ·sqrt(Δt/τc(k,l)), χ ~ N(0,1), so that the intensity
   correlation is ρ(τ) = exp(-τ/τc).
2. Environmental phase noise ψ (from i = 1 on), σ_noise = α·sqrt(Δt/τ_noise). The paper draws
   θ independently per frame ("white", the default here). Because it also speaks of a noise
   correlation radius, the "ou" model offers an Ornstein-Uhlenbeck process with stationary
   standard deviation σ_noise and correlation time τ_noise, for the β-versus-τ_noise study,
   and "walk" a random walk with step σ_noise ("similarly to the phase change related to the
   observed process"), which decorrelates like an extra activity 1/τ = α²/τ_noise.
3. Field U_S = sqrt(I0)·exp(-j(φ + ψ)), imaged through a circular pupil:
   U_cam = IFT{H·FT{U_S}}, and |U_cam|² averaged over 2x2 grid points per camera pixel
   (the paper sums; the factor 4 is absorbed by the detector gain).
4. Detector (optional): photons N_ph = I·N_max/max(I of frame 0) — the gain is fixed once, as
   on a real camera, so frames stay comparable — Poisson shot noise on N_ph, ambient photons
   Poisson(η·N_max) drawn separately (the sum of independent Poisson variables is Poisson with
   the summed mean, so this is the paper's Poisson(N_ph + N_al) while keeping the ground-truth
   draws untouched), then the range N_max + sqrt(N_max) mapped onto 0..2^bits-1 and rounded.
   When the scene asks: the photons scaled by the light level (darkening, exposure steps) and
   Poisson dark current added (:mod:`edgedsm.sim.detector`).

Memory is constant in the number of frames: only the current phase (and noise) is kept.

How it is computed (none of this changes the model above):

* The grid is cut into fixed blocks of rows (``_block_rows``, a function of the size only;
  camera blocks are half as many rows). Every effect's stream is split into one sub-stream per
  block: block 0 draws from the effect's own stream (``rngs[effect]``), block b from a copy of
  it jumped ahead b·(φ-1)·2^128 draws (PCG64 ``jumped``), so sub-streams never overlap. The layout
  never depends on the thread count: ``workers`` only decides which thread handles which
  block, so the frames are bit-identical for any ``workers``.
* Normal numbers χ, θ come from the Box-Muller transform of the block's uniforms (about 3x
  faster than numpy's ziggurat). The uniforms are float32 (24 bits) in both precisions, so a
  single and a double run of a scene use the same draws and differ only by rounding; the
  normal tails are cut beyond 5.8σ, a probability of 8e-9.
* The propagation is a pruned 2-D FFT, exact (no approximation; equal to fft2 → H → ifft2 up to
  rounding): the circular pupil keeps only the band |kx| <= r of spectral columns, so row FFTs
  run on all rows, column FFTs only on the band, and back (about 40 % fewer 1-D transforms at
  speckle size 2).
* Shot noise and ambient photons are exact Poisson draws (:mod:`edgedsm.sim.poisson`: numpy's
  PTRS algorithm in rounds, and an alias table for the constant ambient λ) that take a fixed
  number of draws per pixel and frame, each pixel's own: a tiny change of λ (single against
  double precision, or a little phase noise) changes the counts of the few pixels whose draw
  it decides, not every later draw.
* Blocks run on ``workers`` threads (numpy's generators, ufuncs, scipy.fft and the numba
  kernels release the GIL); |U|², the 2x2 binning and the detector are done per block while
  the data are in cache.
"""

from __future__ import annotations

import itertools
import math
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.fft

from edgedsm.frames import sample_dtype
from edgedsm.sim.activity import tau_c_map
from edgedsm.sim.detector import DetectorRows
from edgedsm.sim.optics import beam_amplitude, pupil_transfer
from edgedsm.sim.scene import Scene
from edgedsm.sim.streams import effect_stream

Precision = Literal["single", "double"]
_TWO_PI = 2.0 * math.pi
_REWRAP_EVERY = 256  # frames between phase re-wraps into [0, 2π) (keeps float32 phases exact)
_BLOCK_POINTS = 1 << 15  # grid points per block: a complex64 block is 256 KiB, stays in L2
_BAND_CHUNK = 32  # spectral columns per column-FFT task (fixed, so batching never varies)

_POOLS: dict[int, ThreadPoolExecutor] = {}
_POOLS_LOCK = threading.Lock()


def _pool(helpers: int) -> ThreadPoolExecutor:
    """Process-wide helper threads, shared by all simulators with the same worker count."""
    with _POOLS_LOCK:
        pool = _POOLS.get(helpers)
        if pool is None:
            pool = _POOLS[helpers] = ThreadPoolExecutor(helpers, thread_name_prefix="edgedsm-sim")
        return pool


def _block_rows(grid: int) -> int:
    """Grid rows per block (even, so that a block covers whole camera rows)."""
    return min(grid, max(2, (_BLOCK_POINTS // grid) & ~1))


def _substreams(root: np.random.Generator, count: int) -> list[np.random.Generator]:
    """``root`` followed by ``count - 1`` non-overlapping jumped copies of it."""
    return [root] + [np.random.Generator(root.bit_generator.jumped(b)) for b in range(1, count)]


def _band_limit(pupil: np.ndarray) -> int | None:
    """Largest |kx| with a non-zero pupil column, or None when pruning would not save work."""
    grid = pupil.shape[1]
    freq = np.abs(np.fft.fftfreq(grid) * grid).astype(np.int64)
    used = pupil.any(axis=0)
    if not used.any():
        return None
    k = int(freq[used].max())
    if 2 * k + 1 >= grid or not np.array_equal(used, freq <= k):
        return None
    return k


@dataclass
class _Scratch:
    """Working arrays of one thread slot (never shared between threads)."""

    uniforms: np.ndarray  # (rows*grid,) float32, whatever the precision
    normals: np.ndarray  # (rows, grid) real
    angle: np.ndarray  # (rows, grid) real
    sin: np.ndarray  # (rows, grid) real
    field: np.ndarray  # (rows, grid) complex
    intensity: np.ndarray  # (rows, grid) real


class Simulator:
    """Stateful frame generator for one scene.

    ``precision`` "single" computes fields in complex64 (fast), "double" in complex128;
    ``workers`` is the number of threads (random draws, FFTs, detector); the frames do not
    depend on it. ``rngs`` maps each simulated effect to its own stream (the first of its
    sub-streams, see the module docstring); absent effects have none.
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
        self._stream_names = tuple(name for name in
                                   ("surface", "activity", "phase_noise", "shot_noise", "ambient_light",
                                    "dark_current")
                                   if name in self.effects)
        self._rows = _block_rows(self.grid)
        self._blocks = -(-self.grid // self._rows)
        self._step0 = np.sqrt(1.0 / tau_c_map(scene)).astype(self._real)  # sqrt(Δt/τc)
        self._amplitude = beam_amplitude(scene.illumination, self.grid, self._real)
        pupil = pupil_transfer(self.size, scene.scene.effective_speckle_size, self._real)
        self._band_k = _band_limit(pupil)
        if self._band_k is None:
            self._pupil_band = pupil
        else:
            k = self._band_k
            self._pupil_band = np.ascontiguousarray(np.concatenate([pupil[:, :k + 1], pupil[:, self.grid - k:]],
                                                                   axis=1))
        self._band = np.empty((self.grid, self._pupil_band.shape[1]), self._complex)
        self._noise_sigma = 0.0
        self._noise_decay = 0.0
        self._noise_step = 0.0
        if "phase_noise" in self.effects:
            noise = scene.phase_noise
            self._noise_sigma = noise.alpha * math.sqrt(1.0 / noise.tau_noise)
            if noise.model == "ou":
                self._noise_decay = math.exp(-1.0 / noise.tau_noise)
            elif noise.model == "walk":
                self._noise_decay = 1.0
            # innovation of ψ_i = a·ψ_{i-1} + step·θ: OU keeps the stationary σ_noise, the walk
            # adds σ_noise per frame
            self._noise_step = self._noise_sigma * math.sqrt(1.0 - self._noise_decay**2) \
                if self._noise_decay < 1.0 else self._noise_sigma
        self._detector = None if scene.detector is None else DetectorRows(scene)
        self._scratch: list[_Scratch | None] = [None] * workers
        self.reset()

    def reset(self) -> None:
        """Back to frame 0 with fresh streams (the same seed gives the same frames)."""
        seed = self.scene.scene.seed
        # effect_stream is looked up at call time so that tests can watch which streams exist
        self.rngs: dict[str, np.random.Generator] = {name: effect_stream(seed, name)
                                                     for name in self._stream_names}
        self._streams = {name: _substreams(rng, self._blocks) for name, rng in self.rngs.items()}
        self.frame_index = 0
        self._phase = np.empty((self.grid, self.grid), self._real)
        self._noise: np.ndarray | None = None
        self._noise_started = False
        self._gain: float | None = None
        self._level = self.scene.light_level(0)  # darkening and exposure steps at this frame
        self._eta = self._ambient_eta(0)

    # -- threading ----------------------------------------------------------------------
    def _parallel(self, task: Callable[[int, int], None], count: int) -> None:
        """Run ``task(index, slot)`` for every index on up to ``workers`` threads.

        Each index owns its rows and sub-streams, so which thread runs it never changes a result.
        """
        slots = min(self.workers, count)
        if slots <= 1:
            for index in range(count):
                task(index, 0)
            return
        counter = itertools.count()  # next() on it is atomic under the GIL: dynamic balancing

        def loop(slot: int) -> None:
            while (index := next(counter)) < count:
                task(index, slot)

        futures = [_pool(self.workers - 1).submit(loop, slot) for slot in range(1, slots)]
        try:
            loop(0)
        finally:
            for future in futures:
                future.result()

    def _scratch_for(self, slot: int) -> _Scratch:
        scratch = self._scratch[slot]
        if scratch is None:
            shape = (self._rows, self.grid)
            scratch = self._scratch[slot] = _Scratch(
                uniforms=np.empty(self._rows * self.grid, np.float32),
                normals=np.empty(shape, self._real), angle=np.empty(shape, self._real),
                sin=np.empty(shape, self._real), field=np.empty(shape, self._complex),
                intensity=np.empty(shape, self._real))
        return scratch

    def _span(self, block: int) -> tuple[int, int]:
        """Grid rows [r0, r1) of a block."""
        r0 = block * self._rows
        return r0, min(r0 + self._rows, self.grid)

    # -- stages -------------------------------------------------------------------------
    def _normals(self, rng: np.random.Generator, out: np.ndarray, scratch: _Scratch) -> np.ndarray:
        """Fill ``out`` with N(0,1) numbers by Box-Muller from ``rng``'s float32 uniforms.

        The uniforms are float32 in both precisions, so single and double runs of a scene use
        the same draws and differ only by rounding.
        """
        half = out.size // 2
        u = scratch.uniforms[:2 * half].reshape(2, half)  # contiguous, as Generator.random(out=) needs
        rng.random(out=u, dtype=np.float32)
        radius = scratch.sin.reshape(-1)[:half]
        np.subtract(1.0, u[0], out=radius, dtype=self._real)  # (0, 1]: log is finite; exact
        np.log(radius, out=radius)
        radius *= -2.0
        np.sqrt(radius, out=radius)
        pairs = out.reshape(2, half)
        angle = np.multiply(u[1], _TWO_PI, out=pairs[1], dtype=self._real)
        np.cos(angle, out=pairs[0])
        np.sin(angle, out=pairs[1])
        pairs *= radius
        return out

    def _phase_block(self, block: int, scratch: _Scratch, step_scale: float, noise_fresh: bool) -> np.ndarray:
        """Advance φ (and ψ) of one block; return φ + ψ for this frame."""
        r0, r1 = self._span(block)
        rows = r1 - r0
        phase = self._phase[r0:r1]
        i = self.frame_index
        if i == 0:
            u = scratch.uniforms[:phase.size].reshape(phase.shape)
            self._streams["surface"][block].random(out=u, dtype=np.float32)
            return np.multiply(u, _TWO_PI, out=phase, dtype=self._real)
        step = self._normals(self._streams["activity"][block], scratch.normals[:rows], scratch)
        step *= self._step0[r0:r1]
        if step_scale != 1.0:
            step *= self._real(step_scale)
        phase += step
        if i % _REWRAP_EVERY == 0:
            np.remainder(phase, _TWO_PI, out=phase)
        if self._noise is None:
            return phase
        noise = self._noise[r0:r1]
        rng = self._streams["phase_noise"][block]
        if noise_fresh:
            # white noise, or the first OU sample drawn from its stationary distribution
            self._normals(rng, noise, scratch)
            noise *= self._real(self._noise_sigma)
        else:
            draw = self._normals(rng, scratch.normals[:rows], scratch)
            draw *= self._real(self._noise_step)
            if self._noise_decay != 1.0:
                noise *= self._real(self._noise_decay)
            noise += draw
            if self._noise_decay == 1.0 and i % _REWRAP_EVERY == 0:
                np.remainder(noise, _TWO_PI, out=noise)  # the walk grows like the phase itself
        return np.add(phase, noise, out=scratch.angle[:rows])

    def _field_block(self, block: int, angle: np.ndarray, scratch: _Scratch) -> np.ndarray:
        """U_S = sqrt(I0)·exp(-j·angle) for one block."""
        r0, r1 = self._span(block)
        rows = r1 - r0
        field = scratch.field[:rows]
        np.cos(angle, out=field.real)
        sin = np.sin(angle, out=scratch.sin[:rows])
        np.negative(sin, out=field.imag)
        if self._amplitude is not None:
            field *= self._amplitude[r0:r1]
        return field

    def _forward_rows(self, block: int, field: np.ndarray) -> None:
        """Row FFTs of one block; keep the pupil's band of columns."""
        r0, r1 = self._span(block)
        spectrum = scipy.fft.fft(field, axis=1, overwrite_x=True, workers=1)
        k = self._band_k
        if k is None:
            self._band[r0:r1] = spectrum
        else:
            self._band[r0:r1, :k + 1] = spectrum[:, :k + 1]
            self._band[r0:r1, k + 1:] = spectrum[:, self.grid - k:]

    def _columns(self, chunk: int, _slot: int = 0) -> None:
        """Column FFT, pupil, inverse column FFT on one chunk of band columns."""
        c0 = chunk * _BAND_CHUNK
        c1 = min(c0 + _BAND_CHUNK, self._band.shape[1])
        spectrum = scipy.fft.fft(self._band[:, c0:c1], axis=0, workers=1)
        spectrum *= self._pupil_band[:, c0:c1]
        self._band[:, c0:c1] = scipy.fft.ifft(spectrum, axis=0, overwrite_x=True, workers=1)

    def _inverse_rows(self, block: int, scratch: _Scratch) -> np.ndarray:
        """|U_cam|² of one block (grid rows), from the band after the column stage."""
        r0, r1 = self._span(block)
        rows = r1 - r0
        k = self._band_k
        if k is None:
            work = self._band[r0:r1]
        else:
            work = scratch.field[:rows]
            work[:, :k + 1] = self._band[r0:r1, :k + 1]
            work[:, k + 1:self.grid - k] = 0
            work[:, self.grid - k:] = self._band[r0:r1, k + 1:]
        camera = scipy.fft.ifft(work, axis=1, overwrite_x=True, workers=1)
        intensity = np.square(camera.real, out=scratch.intensity[:rows])
        intensity += np.square(camera.imag, out=scratch.sin[:rows])
        return intensity

    @staticmethod
    def _bin(grid_intensity: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Average over 2x2 grid points per camera pixel (pixel integration)."""
        g = grid_intensity
        pairs = g[0::2] + g[1::2]
        out = np.add(pairs[:, 0::2], pairs[:, 1::2], out=out)
        out *= 0.25
        return out

    def _run_frame(self, output: Callable[[int, _Scratch, np.ndarray], None]) -> None:
        """Advance one frame: phases, field and forward FFT, column stage, inverse FFT.

        ``output(block, scratch, grid_intensity)`` consumes each block's |U_cam|².
        """
        i = self.frame_index
        drying = self.scene.activity.drying
        step_scale = 1.0 if drying is None or i == 0 else 1.0 / math.sqrt(drying.factor(i))
        noise_fresh = False
        if i > 0 and self._noise_sigma != 0.0:
            if self._noise is None:
                self._noise = np.empty_like(self._phase)
            noise_fresh = not self._noise_started or self._noise_decay == 0.0
            self._noise_started = True

        def forward(block: int, slot: int) -> None:
            scratch = self._scratch_for(slot)
            angle = self._phase_block(block, scratch, step_scale, noise_fresh)
            self._forward_rows(block, self._field_block(block, angle, scratch))

        def inverse(block: int, slot: int) -> None:
            scratch = self._scratch_for(slot)
            output(block, scratch, self._inverse_rows(block, scratch))

        self._parallel(forward, self._blocks)
        self._parallel(self._columns, -(-self._band.shape[1] // _BAND_CHUNK))
        self._parallel(inverse, self._blocks)
        self.frame_index += 1

    def _propagate(self, field: np.ndarray) -> np.ndarray:
        """|IFT{H·FT{field}}|² on the object grid through the pruned FFT (state untouched)."""
        out = np.empty(field.shape, self._real)

        def forward(block: int, slot: int) -> None:
            r0, r1 = self._span(block)
            self._forward_rows(block, field[r0:r1].astype(self._complex))

        def inverse(block: int, slot: int) -> None:
            r0, r1 = self._span(block)
            out[r0:r1] = self._inverse_rows(block, self._scratch_for(slot))

        self._parallel(forward, self._blocks)
        self._parallel(self._columns, -(-self._band.shape[1] // _BAND_CHUNK))
        self._parallel(inverse, self._blocks)
        return out

    # -- detector -----------------------------------------------------------------------
    def _detect_rows(self, intensity: np.ndarray, block: int, laser_on: bool, out: np.ndarray) -> None:
        """Detector model (edgedsm.sim.detector) on camera rows of one block, drawing from that
        block's sub-streams."""
        assert self._detector is not None and self._gain is not None
        self._detector.rows(intensity, self._gain * self._level if laser_on else 0.0,
                            lambda effect: self._streams[effect][block], out, self._eta)

    def _ambient_eta(self, frame: int) -> float:
        ambient = self.scene.ambient_light
        return 0.0 if ambient is None else ambient.eta_at(frame)

    def _camera_rows(self, height: int) -> int:
        """Camera rows per detector block for an image of ``height`` rows."""
        if height == self.size:
            return self._rows // 2
        return max(1, -(-height // self._blocks))

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
        out = np.empty(intensity.shape, self.output_dtype)
        rows = self._camera_rows(intensity.shape[0])
        count = min(self._blocks, -(-intensity.shape[0] // rows))

        def task(block: int, _slot: int) -> None:
            r0, r1 = block * rows, min((block + 1) * rows, intensity.shape[0])
            self._detect_rows(intensity[r0:r1], block, laser_on, out[r0:r1])

        self._parallel(task, count)
        return out

    # -- public -------------------------------------------------------------------------
    def next_grid_intensity(self) -> np.ndarray:
        """Advance one frame; |U_cam|² on the 2N grid, before pixel integration and detection."""
        out = np.empty((self.grid, self.grid), self._real)

        def keep(block: int, _scratch: _Scratch, grid_intensity: np.ndarray) -> None:
            r0, r1 = self._span(block)
            out[r0:r1] = grid_intensity

        self._run_frame(keep)
        return out

    def next_intensity(self) -> np.ndarray:
        """Advance one frame; irradiance per camera pixel in relative units (mean <I0>)."""
        out = np.empty((self.size, self.size), self._real)

        def binned(block: int, _scratch: _Scratch, grid_intensity: np.ndarray) -> None:
            r0, r1 = self._span(block)
            self._bin(grid_intensity, out[r0 // 2:r1 // 2])

        self._run_frame(binned)
        return out

    def next_frame(self, laser_on: bool = True) -> np.ndarray:
        """Advance one frame and return what the camera delivers."""
        self._level = self.scene.light_level(self.frame_index)
        self._eta = self._ambient_eta(self.frame_index)
        if self.scene.detector is None or self._gain is None:
            return self.detect(self.next_intensity(), laser_on)
        # gain known: detect each block while its intensity is still in cache (same draws as
        # detect(next_intensity()), since camera blocks and sub-streams coincide)
        out = np.empty((self.size, self.size), self.output_dtype)

        def detected(block: int, scratch: _Scratch, grid_intensity: np.ndarray) -> None:
            r0, r1 = self._span(block)
            rows = (r1 - r0) // 2
            binned = self._bin(grid_intensity, scratch.angle[:rows, :self.size])
            self._detect_rows(binned, block, laser_on, out[r0 // 2:r1 // 2])

        self._run_frame(detected)
        return out

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
        return sample_dtype(detector.bits)


def simulate(scene: Scene, precision: Precision = "single", workers: int = 1) -> Iterator[np.ndarray]:
    """Yield the scene's frames: uint8 (<= 8-bit detector), uint16 (wider), float without detector."""
    yield from Simulator(scene, precision=precision, workers=workers).frames()
