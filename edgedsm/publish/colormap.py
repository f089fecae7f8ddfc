"""Activity maps as colour pictures for viewers (Home Assistant's image entity): an 8-bit
colour-mapped PNG with a colour bar labelled with the map's range. Pure, no I/O.

For people, not programs: the exact values travel in the 16-bit map (``edgedsm.publish.mapcodec``).
The map is downsampled like the 16-bit one and drawn by edgedsm's one colour renderer
(``edgedsm.imageio.colour_picture``: linear from its minimum, index 0, to its maximum, 255; the
dashboard and the saved pictures use it too); a bar on the right shows the scale, the maximum at
its top and the minimum at its bottom.
"""

from __future__ import annotations

import cv2
import numpy as np

from edgedsm import imageio
from edgedsm.imageio import COLORMAPS
from edgedsm.publish.errors import MapCodecError
from edgedsm.publish.mapcodec import downsample_map

BAR_WIDTH = 16
GAP = 6
LABEL_WIDTH = 72
#: Colour bars are never shorter than this (labels need the room); small maps are padded.
MIN_HEIGHT = 64


def colour_indices(values: np.ndarray) -> tuple[np.ndarray, float, float]:
    """``(uint8 indices, low, high)``: the map scaled linearly from its min (0) to its max (255);
    MapCodecError for a NaN or inf (a published map is finite)."""
    data = np.asarray(values, dtype=np.float64)
    if not np.isfinite(data).all():
        raise MapCodecError("a colour map needs finite values (NaN or inf found)")
    return imageio.colour_indices(data)


def _label(value: float) -> str:
    return f"{value:.3g}"


def render_colour_map(values: np.ndarray, *, colormap: str = "turbo", max_size: int | None = 512,
                      title: str | None = None) -> np.ndarray:
    """The BGR picture: the colour-mapped map, then a labelled colour bar on the right."""
    if colormap not in COLORMAPS:
        raise MapCodecError(f"unknown colour map {colormap!r} (one of {', '.join(COLORMAPS)})")
    data = downsample_map(values, max_size)
    colour_indices(data)  # finite, or MapCodecError
    picture, low, high = imageio.colour_picture(data, colormap)
    rows, cols = picture.shape[:2]
    height = max(rows, MIN_HEIGHT)
    canvas = np.full((height, cols + GAP + BAR_WIDTH + LABEL_WIDTH, 3), 255, np.uint8)
    canvas[:rows, :cols] = picture
    canvas[:, cols + GAP:cols + GAP + BAR_WIDTH] = imageio.colour_ramp(height, BAR_WIDTH, colormap)
    text_x = cols + GAP + BAR_WIDTH + 4
    font, scale, black = cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0)
    cv2.putText(canvas, _label(high), (text_x, 12), font, scale, black, 1, cv2.LINE_AA)
    cv2.putText(canvas, _label(low), (text_x, height - 4), font, scale, black, 1, cv2.LINE_AA)
    if title:
        cv2.putText(canvas, title[:10], (text_x, height // 2 + 4), font, scale, black, 1, cv2.LINE_AA)
    return canvas


def encode_colour_png(values: np.ndarray, *, colormap: str = "turbo", max_size: int | None = 512,
                      title: str | None = None, compression: int = 3) -> bytes:
    """The picture of :func:`render_colour_map` as an 8-bit RGB PNG."""
    canvas = render_colour_map(values, colormap=colormap, max_size=max_size, title=title)
    ok, buffer = cv2.imencode(".png", canvas, [cv2.IMWRITE_PNG_COMPRESSION, int(compression)])
    if not ok:
        raise MapCodecError("OpenCV could not encode the colour map as PNG")
    return buffer.tobytes()
