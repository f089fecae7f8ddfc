"""Illumination profile and imaging pupil of the §2A model (pure numpy)."""

from __future__ import annotations

import numpy as np

from edgedsm.sim.scene import Illumination


def beam_amplitude(illumination: Illumination | None, grid: int, dtype) -> np.ndarray | None:
    """sqrt(I0) on the object grid (spacing δ = Δ/2), or None for uniform light (I0 = 1).

    Gaussian beam: I0 = exp(-δ²[(k-Nx)² + (l-Ny)²]/Ω²) with Ω in camera pixels (paper §2B).
    """
    if illumination is None or illumination.kind == "uniform":
        return None
    half = grid // 2
    coords = (np.arange(grid, dtype=np.float64) - half) * 0.5  # in camera pixels
    r2 = coords[:, None] ** 2 + coords[None, :] ** 2
    return np.exp(-r2 / (2.0 * illumination.omega**2)).astype(dtype)


def pupil_radius(size: int, speckle_size: float) -> float:
    """Cut-off of the circular pupil in frequency samples of the 2·size grid.

    The coherent cut-off D/(2λf) times the field length size·Δ gives size/(2·s) where
    s = λf/(DΔ) is the mean speckle size in camera pixels.
    """
    return size / (2.0 * speckle_size)


def pupil_transfer(size: int, speckle_size: float, dtype) -> np.ndarray:
    """circ(H) on the 2·size grid in FFT order, scaled so that <|U_cam|²> = <I0>."""
    grid = 2 * size
    freq = np.fft.fftfreq(grid) * grid
    r2 = freq[:, None] ** 2 + freq[None, :] ** 2
    inside = r2 <= pupil_radius(size, speckle_size) ** 2
    fill = inside.mean()  # energy kept by the pupil for a delta-correlated field
    return (inside / np.sqrt(fill)).astype(dtype)
