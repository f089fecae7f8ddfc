"""Region shapes: one pydantic model per shape (rect, circle, ring, polygon, text, mask, full),
shared by the daemon's ``[[regions]]`` and a scene's ``[[activity.regions]]``, and their
rasterisation into boolean masks (pure, no I/O except `load_mask_image`).

Coordinates are in pixels of the grid being drawn on, scaled by ``scale``: the simulator
draws the camera-pixel geometry of a scene onto its 2x finer object grid with ``scale=2``.
``x`` is the column and ``y`` the row; rectangles and text are anchored at their top-left.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal

import cv2
import numpy as np
from pydantic import Field, model_validator

from edgedsm.errors import ConfigError
from edgedsm.validation import StrictModel

_FONT = cv2.FONT_HERSHEY_SIMPLEX
#: Largest coordinate or length, px (16384 px sensors exist; this leaves room for margins).
LIMIT_PX = 1e5

Coordinate = Annotated[float, Field(ge=-LIMIT_PX, le=LIMIT_PX)]
Point = tuple[Coordinate, Coordinate]
#: (x0, y0, x1, y1): the smallest axis-aligned box around a shape, px.
Bounds = tuple[float, float, float, float]


class Full(StrictModel):
    """The whole frame."""

    shape: Literal["full"] = Field("full", description="the whole frame")

    def draw(self, grid: tuple[int, int], scale: float = 1.0, base_dir: Path = Path(".")) -> np.ndarray:
        return np.ones(grid, bool)

    def bounds(self) -> Bounds | None:
        return None  # fits every frame


class Rect(StrictModel):
    shape: Literal["rect"] = Field(description="axis-aligned rectangle")
    x: float = Field(0, ge=-LIMIT_PX, le=LIMIT_PX, description="column of the top-left corner, px")
    y: float = Field(0, ge=-LIMIT_PX, le=LIMIT_PX, description="row of the top-left corner, px")
    width: float = Field(gt=0, le=LIMIT_PX, description="width, px")
    height: float = Field(gt=0, le=LIMIT_PX, description="height, px")

    def draw(self, grid: tuple[int, int], scale: float = 1.0, base_dir: Path = Path(".")) -> np.ndarray:
        return rect_mask(grid, self.x, self.y, self.width, self.height, scale)

    def bounds(self) -> Bounds | None:
        return (self.x, self.y, self.x + self.width, self.y + self.height)


class Circle(StrictModel):
    shape: Literal["circle"] = Field(description="disc")
    cx: float = Field(0, ge=-LIMIT_PX, le=LIMIT_PX, description="centre column, px")
    cy: float = Field(0, ge=-LIMIT_PX, le=LIMIT_PX, description="centre row, px")
    radius: float = Field(gt=0, le=LIMIT_PX, description="radius, px")

    def draw(self, grid: tuple[int, int], scale: float = 1.0, base_dir: Path = Path(".")) -> np.ndarray:
        return circle_mask(grid, self.cx, self.cy, self.radius, scale)

    def bounds(self) -> Bounds | None:
        return (self.cx - self.radius, self.cy - self.radius, self.cx + self.radius, self.cy + self.radius)


class Ring(StrictModel):
    shape: Literal["ring"] = Field(description="annulus")
    cx: float = Field(0, ge=-LIMIT_PX, le=LIMIT_PX, description="centre column, px")
    cy: float = Field(0, ge=-LIMIT_PX, le=LIMIT_PX, description="centre row, px")
    inner_radius: float = Field(ge=0, le=LIMIT_PX, description="inner radius, px")
    outer_radius: float = Field(gt=0, le=LIMIT_PX, description="outer radius, px")

    @model_validator(mode="after")
    def _radii(self) -> Ring:
        if self.outer_radius <= self.inner_radius:
            raise ValueError("outer_radius must be larger than inner_radius")
        return self

    def draw(self, grid: tuple[int, int], scale: float = 1.0, base_dir: Path = Path(".")) -> np.ndarray:
        return ring_mask(grid, self.cx, self.cy, self.inner_radius, self.outer_radius, scale)

    def bounds(self) -> Bounds | None:
        r = self.outer_radius
        return (self.cx - r, self.cy - r, self.cx + r, self.cy + r)


class Polygon(StrictModel):
    shape: Literal["polygon"] = Field(description="filled polygon")
    points: list[Point] = Field(min_length=3, max_length=1000, description="[[x, y], ...] vertices, px")

    @model_validator(mode="after")
    def _has_area(self) -> Polygon:
        if polygon_area(self.points) < 1e-6:
            raise ValueError("the polygon has no area (identical or collinear points)")
        return self

    def draw(self, grid: tuple[int, int], scale: float = 1.0, base_dir: Path = Path(".")) -> np.ndarray:
        return polygon_mask(grid, self.points, scale)

    def bounds(self) -> Bounds | None:
        xs, ys = [p[0] for p in self.points], [p[1] for p in self.points]
        return (min(xs), min(ys), max(xs), max(ys))


class Text(StrictModel):
    shape: Literal["text"] = Field(description="letters")
    text: str = Field(min_length=1, max_length=64, description="letters drawn as the region, e.g. 'IOMT'")
    x: float = Field(0, ge=-LIMIT_PX, le=LIMIT_PX, description="column of the top-left corner, px")
    y: float = Field(0, ge=-LIMIT_PX, le=LIMIT_PX, description="row of the top-left corner, px")
    height: float = Field(gt=1, le=LIMIT_PX, description="cap height of the letters, px")
    stroke: float = Field(0.18, gt=0.01, le=1.0, description="stroke width as a fraction of the height")

    def draw(self, grid: tuple[int, int], scale: float = 1.0, base_dir: Path = Path(".")) -> np.ndarray:
        return text_mask(grid, self.text, self.x, self.y, self.height, scale, self.stroke)

    def bounds(self) -> Bounds | None:
        width, height = text_extent(self.text, self.height, self.stroke)
        return (self.x, self.y, self.x + width, self.y + height)


class Mask(StrictModel):
    shape: Literal["mask"] = Field(description="grey image")
    path: Path = Field(description="grey image, relative to the file that names it; resized to the frame")
    threshold: int = Field(128, ge=1, le=255, description="grey level from which a pixel is inside")

    def draw(self, grid: tuple[int, int], scale: float = 1.0, base_dir: Path = Path(".")) -> np.ndarray:
        return load_mask_image(self.resolved(base_dir), grid, self.threshold)

    def resolved(self, base_dir: Path) -> Path:
        return self.path if self.path.is_absolute() else base_dir / self.path

    def bounds(self) -> Bounds | None:
        return None  # resized to the frame


Shape = Full | Rect | Circle | Ring | Polygon | Text | Mask
SHAPE_NAMES = ("full", "rect", "circle", "ring", "polygon", "text", "mask")


def polygon_area(points: list[tuple[float, float]]) -> float:
    """Area enclosed by the vertices (shoelace formula), px²; 0 for a degenerate polygon."""
    twice = 0.0
    for (x0, y0), (x1, y1) in zip(points, points[1:] + points[:1], strict=True):
        twice += x0 * y1 - x1 * y0
    return abs(twice) / 2 if math.isfinite(twice) else 0.0


def outside_part(bounds: Bounds | None, frame: tuple[int, int]) -> str:
    """Which sides of the frame (rows, columns) the bounds cross; "" when inside."""
    if bounds is None:
        return ""
    x0, y0, x1, y1 = bounds
    rows, cols = frame
    sides = [side for side, out in (("left", x0 < 0), ("top", y0 < 0), ("right", x1 > cols),
                                    ("bottom", y1 > rows)) if out]
    return ", ".join(sides)



def rect_mask(shape: tuple[int, int], x: float, y: float, width: float, height: float,
              scale: float = 1.0) -> np.ndarray:
    """Axis-aligned rectangle [x, x+width) x [y, y+height)."""
    rows, cols = _grid(shape)
    x0, y0, x1, y1 = x * scale, y * scale, (x + width) * scale, (y + height) * scale
    return (cols + 0.5 >= x0) & (cols + 0.5 < x1) & (rows + 0.5 >= y0) & (rows + 0.5 < y1)


def circle_mask(shape: tuple[int, int], cx: float, cy: float, radius: float,
                scale: float = 1.0) -> np.ndarray:
    """Disc of ``radius`` around the centre (cx, cy)."""
    return ring_mask(shape, cx, cy, 0.0, radius, scale)


def ring_mask(shape: tuple[int, int], cx: float, cy: float, inner_radius: float,
              outer_radius: float, scale: float = 1.0) -> np.ndarray:
    """Annulus inner_radius <= r < outer_radius around (cx, cy); pixel centres are tested."""
    rows, cols = _grid(shape)
    r2 = (cols + 0.5 - cx * scale) ** 2 + (rows + 0.5 - cy * scale) ** 2
    return (r2 >= (inner_radius * scale) ** 2) & (r2 < (outer_radius * scale) ** 2)


def polygon_mask(shape: tuple[int, int], points: list[tuple[float, float]],
                 scale: float = 1.0) -> np.ndarray:
    """Filled polygon through (x, y) vertices."""
    canvas = np.zeros(shape, np.uint8)
    pts = np.round(np.asarray(points, float) * scale).astype(np.int32)
    cv2.fillPoly(canvas, [pts], 1)
    return canvas.astype(bool)


def text_mask(shape: tuple[int, int], text: str, x: float, y: float, height: float,
              scale: float = 1.0, stroke: float = 0.18) -> np.ndarray:
    """Letters of ``text`` (Hershey sans-serif), cap height ``height`` px, top-left at (x, y).

    ``stroke`` is the line thickness as a fraction of the cap height.
    """
    canvas = np.zeros(shape, np.uint8)
    font_scale, thickness, (_, th), _ = _text_layout(text, height * scale, stroke)
    origin = (round(x * scale), round(y * scale + th))
    cv2.putText(canvas, text, origin, _FONT, font_scale, 1, thickness, cv2.LINE_8)
    return canvas.astype(bool)


def text_extent(text: str, height: float, stroke: float = 0.18) -> tuple[float, float]:
    """(width, height) of the box ``text_mask`` draws the letters in, px (descenders included)."""
    _, thickness, (tw, th), baseline = _text_layout(text, height, stroke)
    return float(tw + thickness), float(th + baseline + thickness)


def _text_layout(text: str, h: float, stroke: float) -> tuple[float, int, tuple[int, int], int]:
    thickness = max(1, round(stroke * h))
    (_, base_h), _ = cv2.getTextSize(text, _FONT, 1.0, thickness)
    font_scale = h / max(base_h, 1)
    size, baseline = cv2.getTextSize(text, _FONT, font_scale, thickness)
    return font_scale, thickness, size, baseline


def load_mask_image(path: Path, shape: tuple[int, int], threshold: int = 128) -> np.ndarray:
    """A grey image resized (nearest neighbour) to ``shape``; pixels >= threshold are inside."""
    image = load_mask_image_or_none(path)
    if image is None:
        raise ConfigError(f"mask image {path}: cannot be read (missing or not an image)")
    if image.shape != shape:
        image = cv2.resize(image, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST)
    return image >= threshold


def load_mask_image_or_none(path: Path) -> np.ndarray | None:
    """The grey image at ``path``, or None when it is missing or not an image. Its header is
    checked against the memory budget before it is decoded: a header claiming more is a
    ``BudgetError`` (exit 65) naming the mask and the claim (``edgedsm.frameio.budget``)."""
    from edgedsm.frameio.budget import image_size
    from edgedsm.frameio.images import decode_image

    if image_size(path) is None:
        return None  # missing, unknown or damaged: never handed to a decoder
    return decode_image(path, cv2.IMREAD_GRAYSCALE, "header of the mask")


def _grid(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    rows = np.arange(shape[0], dtype=np.float64)[:, None]
    cols = np.arange(shape[1], dtype=np.float64)[None, :]
    return rows, cols
