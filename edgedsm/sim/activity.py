"""Activity maps: τc per point of the object grid, and the region masks of a scene."""

from __future__ import annotations

import numpy as np

from edgedsm.sim.scene import Region, Scene


def region_mask(region: Region, shape: tuple[int, int], scale: float, base_dir) -> np.ndarray:
    """Boolean mask of one scene region on a grid of ``shape`` (``scale`` grid px per camera px)."""
    return region.draw(shape, scale, base_dir)


def tau_c_map(scene: Scene, scale: int = 2) -> np.ndarray:
    """τc (in Δt) at every point of a grid ``scale`` times finer than the camera, float64.

    The background has ``activity.tau_c``; regions paint over it in file order.
    """
    size = scene.scene.size * scale
    tau = np.full((size, size), scene.activity.tau_c, dtype=np.float64)
    for region in scene.activity.regions:
        tau[region_mask(region, tau.shape, scale, scene.base_dir)] = region.tau_c
    return tau


def region_masks(scene: Scene) -> dict[str, np.ndarray]:
    """Camera-grid masks of the scene: each named region (as drawn, later ones on top),
    ``"regions"`` (union of all) and ``"background"`` (the rest).

    Unnamed regions are called ``region<i>``.
    """
    shape = scene.shape
    owner = np.full(shape, -1, dtype=np.int32)
    for index, region in enumerate(scene.activity.regions):
        owner[region_mask(region, shape, 1.0, scene.base_dir)] = index
    masks = {}
    for index, region in enumerate(scene.activity.regions):
        masks[region.name or f"region{index}"] = owner == index
    masks["regions"] = owner >= 0
    masks["background"] = owner < 0
    return masks


def decorrelation_lags(scene: Scene, frames: np.ndarray, tau_c: float | None = None) -> np.ndarray:
    """The truth of a drying scene's decorrelation time: for each frame t of ``frames`` (ints), the
    lag τ (Δt, float64) at which ∫_{t-τ}^{t} dt'/τc(t') = 1, i.e. the speckle at t has decorrelated
    to 1/e from the frame τ before it; inf where even frame 0 is closer than that.

    The simulator's phase step into frame i (i >= 1) has variance Δt/(τc·factor(i)) (``Drying``;
    ``tau_c``: the surface's τc before drying, default the background's ``activity.tau_c``), so
    the phase difference between frames s and t has variance Σ_{s<i<=t} 1/(τc·factor(i)) and the
    intensity correlation is exp(-that) (Gaussian field, g2 - 1 = |g1|²); the rate is taken as
    constant within each frame interval, which makes the lag continuous."""
    drying = scene.activity.drying
    base = scene.activity.tau_c if tau_c is None else float(tau_c)
    at = np.asarray(frames, np.int64)
    last = int(at.max(initial=0))
    factors = np.ones(last) if drying is None else np.array([drying.factor(i) for i in range(1, last + 1)])
    reached = np.concatenate([[0.0], np.cumsum(1.0 / (base * factors))])  # ∫_0^i dt/τc at frame i
    target = reached[at] - 1.0
    start = np.interp(target, reached, np.arange(last + 1, dtype=np.float64))
    return np.where(target >= 0.0, at - start, np.inf)
