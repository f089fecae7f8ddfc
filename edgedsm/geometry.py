"""Rasterisation of region shapes into boolean masks (pure, no I/O except `load_mask_image`).

Coordinates are in pixels of the grid being drawn on, scaled by ``scale``: the simulator
draws the camera-pixel geometry of a scene onto its 2x finer object grid with ``scale=2``.
``x`` is the column and ``y`` the row; rectangles and text are anchored at their top-left.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from edgedsm.errors import ConfigError

_FONT = cv2.FONT_HERSHEY_SIMPLEX


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
    h = height * scale
    thickness = max(1, round(stroke * h))
    (_, base_h), _ = cv2.getTextSize(text, _FONT, 1.0, thickness)
    font_scale = h / max(base_h, 1)
    (_, th), _ = cv2.getTextSize(text, _FONT, font_scale, thickness)
    origin = (round(x * scale), round(y * scale + th))
    cv2.putText(canvas, text, origin, _FONT, font_scale, 1, thickness, cv2.LINE_8)
    return canvas.astype(bool)


def load_mask_image(path: Path, shape: tuple[int, int], threshold: int = 128) -> np.ndarray:
    """A grey image resized (nearest neighbour) to ``shape``; pixels >= threshold are inside."""
    image = load_mask_image_or_none(path)
    if image is None:
        raise ConfigError(f"mask image {path}: cannot be read (missing or not an image)")
    if image.shape != shape:
        image = cv2.resize(image, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST)
    return image >= threshold


def load_mask_image_or_none(path: Path) -> np.ndarray | None:
    """The grey image at ``path``, or None when it is missing or not an image."""
    return cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)


def _grid(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    rows = np.arange(shape[0], dtype=np.float64)[:, None]
    cols = np.arange(shape[1], dtype=np.float64)[None, :]
    return rows, cols
