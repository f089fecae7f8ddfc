"""edgedsm: dynamic speckle activity maps from the lab to the factory floor.

Reference: Levchenko et al., "Noise analysis in outdoor dynamic speckle measurement"
(Optica, 2022); equations are cited as "Eq. n" of that paper throughout.

The Python API (a notebook's names; docs/python.md, README "Python API")::

    import edgedsm
    frames = edgedsm.open_frames("run.avi", channel="green").window(0, 200)  # (200, H, W)
    activity = edgedsm.s2(frames, lag=10)          # (H, W) float64, Eq. 2
    tau = edgedsm.tau_c(frames)                     # frames; K = N/2 as the daemon's
    edgedsm.save_map_png("s2.png", activity, title="S2")

Every name of ``__all__`` is imported on first use (PEP 562): ``import edgedsm`` alone loads no
numpy, OpenCV or numba, so the command line starts fast. The names are resolved by module path
strings so that this package, which every layer may read for ``__version__``, stays at the
bottom of the layers (tests/unit/test_house.py): it re-exports, it computes nothing.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

#: Public name -> the module that defines it.
_EXPORTS: dict[str, str] = {
    # the paper's estimators, batch references (float64 maps) and the streaming engine
    **dict.fromkeys(("s1", "s2", "s3", "temporal_sigma", "all_maps"), "edgedsm.estimators.batch"),
    **dict.fromkeys(("tau_c", "tau_c_bounds", "TauC"), "edgedsm.estimators.correlation_time"),
    "SlidingWindow": "edgedsm.estimators.streaming",
    # the field's other descriptors (BSLTL's definitions; docs/descriptors.md)
    **dict.fromkeys(("fujii", "gd", "im", "contrast", "skewness", "kurtosis", "mhi", "band_low", "band_high",
                     "band_ratio"), "edgedsm.estimators.descriptors"),
    # frames in: every file format analyze reads; frames made: the simulator and its scenes
    "open_frames": "edgedsm.frameio",
    **dict.fromkeys(("load_scene", "simulate", "Simulator", "Scene"), "edgedsm.sim"),
    # pictures out: the one colour renderer of maps
    **dict.fromkeys(("save_map_png", "colour_picture", "MapAxes"), "edgedsm.imageio"),
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'edgedsm' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})

