"""The built-in default scene (the paper's two-level logo object; config/scenes/logos.toml)."""

from __future__ import annotations

from pathlib import Path

from edgedsm.sim.scene import Scene, scene_from_dict
from edgedsm.sim.scene import load_scene as load_scene_file

#: The name that stands for the built-in scene wherever a scene file is asked for (CLI and API).
DEFAULT_NAME = "default"


def _logo(text: str, y: float) -> dict:
    return {"shape": "text", "text": text, "x": 48, "y": y, "height": 62, "stroke": 0.21,
            "tau_c": 10.0, "name": text}


DEFAULT_SCENE = {
    "scene": {"size": 256, "frames": 200, "seed": 1, "speckle_size": 2.0},
    "activity": {"tau_c": 50.0, "regions": [_logo("IOMT", 45), _logo("ETRI", 150)]},
    "detector": {"n_max": 1000, "bits": 8},
}


def default_scene() -> Scene:
    """A fresh copy of the built-in default scene."""
    return scene_from_dict(DEFAULT_SCENE, "<built-in default scene>")


def load_scene(path: str | Path) -> Scene:
    """A scene TOML file, or the built-in default scene for ``"default"`` (as the CLI's ``--scene``)."""
    return default_scene() if str(path) == DEFAULT_NAME else load_scene_file(path)
