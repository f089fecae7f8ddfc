"""Maps for the page (pure): a decoded map as a colour PNG, the colour bar, and the statistics
and TOML ``[[regions]]`` block of a region drawn in the editor."""

from __future__ import annotations

import json
from typing import Annotated, Any

import cv2
import numpy as np
from pydantic import Field, TypeAdapter

from edgedsm import geometry
from edgedsm.analysis import region_stats
from edgedsm.errors import EstimatorError
from edgedsm.imageio import colour_picture, colour_ramp

COLORMAP = "viridis"  # perceptually uniform, readable by colour-blind operators
#: The editor's shapes, in camera pixels (the daemon's coordinates), without region settings.
EditorShape = Annotated[geometry.Rect | geometry.Circle | geometry.Polygon, Field(discriminator="shape")]
_SHAPE = TypeAdapter(EditorShape)


def colour_png(values: np.ndarray) -> bytes:
    """The map scaled from its minimum (dark blue) to its maximum (yellow), as an RGB PNG, drawn
    by edgedsm's one colour renderer (``edgedsm.imageio.colour_picture``)."""
    picture, _, _ = colour_picture(values, COLORMAP)
    ok, png = cv2.imencode(".png", picture)
    if not ok:  # pragma: no cover - OpenCV encodes any uint8 image
        raise ValueError("PNG encoding failed")
    return png.tobytes()


def colour_bar_png(height: int = 256, width: int = 16) -> bytes:
    """The colour scale, maximum at the top."""
    return cv2.imencode(".png", colour_ramp(height, width, COLORMAP))[1].tobytes()


def parse_shape(data: Any) -> geometry.Rect | geometry.Circle | geometry.Polygon:
    """A drawn shape (``{"shape": "rect", "x": .., ...}``); ``pydantic.ValidationError`` when malformed."""
    return _SHAPE.validate_python(data)


def shape_stats(values: np.ndarray, source_shape: tuple[int, int], shape: geometry.Rect | geometry.Circle
                | geometry.Polygon) -> dict[str, Any]:
    """Statistics of the map under ``shape`` (camera pixels; the map may be downsampled from
    ``source_shape``), as in the daemon's stats: pixels counted on the map as published."""
    scale = values.shape[0] / source_shape[0] if source_shape[0] > 0 else 1.0
    mask = shape.draw(values.shape, scale)
    try:
        stats = region_stats(values, mask).as_dict()
    except EstimatorError:
        return {"pixels": 0, "mean": None, "std": None, "p05": None, "median": None, "p95": None}
    return stats


def region_toml(name: str, shape: geometry.Rect | geometry.Circle | geometry.Polygon,
                thresholds: dict[str, float] | None = None) -> str:
    """The ``[[regions]]`` block a commissioning engineer pastes into the daemon's config."""
    lines = ["[[regions]]", f"name = {json.dumps(name)}"]
    for key, value in shape.model_dump().items():
        if key == "points":
            value = "[" + ", ".join(f"[{_num(x)}, {_num(y)}]" for x, y in value) + "]"
        elif isinstance(value, str):
            value = json.dumps(value)
        else:
            value = _num(value)
        lines.append(f"{key} = {value}")
    for key, value in (thresholds or {"wet_above": 0.30, "dry_below": 0.16}).items():
        lines.append(f"{key} = {_num(value)}")
    return "\n".join(lines) + "\n"


def _num(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else f"{value:.6g}"

