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
