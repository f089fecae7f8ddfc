"""Running the planned simulations: one optical run, detected at every ambient level it needs."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from typing import Any, Protocol

import numpy as np

from edgedsm.estimators import all_maps
from edgedsm.sim import Simulator, scene_from_dict
from edgedsm_lab.report.plan import Optical, Settings, scene_dict

Maps = dict[str, np.ndarray]
MapStore = dict[tuple["Optical", float], Maps]

class ProgressBar(Protocol):
    """What :func:`reproduce` needs of a progress bar (tqdm fits)."""

    def update(self, n: int = 1) -> Any: ...

    def close(self) -> Any: ...


ProgressFactory = Callable[[int], ProgressBar]
"""Called once with the total number of frames to simulate; returns the bar to update."""

def simulate_maps(settings: Settings, key: Optical, etas: Iterable[float],
                  regions: Sequence[dict[str, Any]],
                  on_frame: Callable[[], None] | None = None) -> dict[float, Maps]:
    """Simulate one optical run once, detect it at every η; per η the S1/S2/S3 maps and the
    temporal mean in grey levels ("mean"), all float32.

    The detectors are separate simulators with the same seed, so their laser shot noise is the
    same draw and only the ambient light differs between them.
    """
    levels = sorted(set(etas))
    scenes = {eta: scene_from_dict(scene_dict(settings, key, eta, regions), source=str(key))
              for eta in levels}
    optics = Simulator(scenes[levels[0]])
    detectors = {eta: Simulator(scene) for eta, scene in scenes.items()}
    shape = (settings.frames, settings.size, settings.size)
    stacks = {eta: np.empty(shape, optics.output_dtype) for eta in levels}
    for index in range(settings.frames):
        intensity = optics.next_intensity()
        for eta in levels:
            stacks[eta][index] = detectors[eta].detect(intensity)
        if on_frame is not None:
            on_frame()
    result = {}
    for eta in levels:
        stack = stacks.pop(eta)
        maps = all_maps(stack, settings.lag, q=settings.q)
        maps["mean"] = stack.mean(axis=0, dtype=np.float64)  # grey levels, for the signal level
        result[eta] = {name: value.astype(np.float32) for name, value in maps.items()}
    return result


def run_plan(settings: Settings, plan: dict[Optical, set[float]],
             regions: Sequence[dict[str, Any]],
             progress: ProgressFactory | None = None) -> MapStore:
    """Run every simulation of ``plan``; maps keyed by (optical run, η)."""
    bar = progress(len(plan) * settings.frames) if progress is not None else None
    on_frame = (lambda: bar.update(1)) if bar is not None else None
    results: MapStore = {}
    try:
        for key, etas in plan.items():
            for eta, maps in simulate_maps(settings, key, etas, regions, on_frame).items():
                results[(key, eta)] = maps
    finally:
        if bar is not None:
            bar.close()
    return results


# -- measures on maps -------------------------------------------------------------------------
