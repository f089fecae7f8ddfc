"""Writing frame stacks and activity-map pictures (OpenCV + numpy).

Frame stacks: ``.npy`` (N, H, W), multi-page ``.tif``/``.tiff`` or a ``printf`` pattern such as
``frames/%05d.png``. Reading any frame source is ``edgedsm.frameio`` (streaming, one layer for
every command); recordings with timestamps are ``edgedsm record`` (``edgedsm.frameio.recording``).

Colour: :func:`colour_picture` and :func:`colour_ramp` are the one renderer of a map in colours,
used by every picture edgedsm makes (``save_map_png`` here; Home Assistant's colour maps,
``edgedsm.publish.colormap``; the dashboard's maps and colour bar, ``edgedsm.dashboard.maps``):
the same map, range and colour map give the same pixels everywhere (tests/unit/test_imageio.py).
"""

from __future__ import annotations

import contextlib
import math
import os
import tempfile
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

import cv2
import numpy as np

from edgedsm.errors import DataError


class ImageIOError(DataError):
    """A frame file could not be read or written (exit code 65: the data, not the program)."""


#: OpenCV colour maps by the names the config accepts (viridis: perceptually uniform, readable
#: by colour-blind operators; the pictures' and the dashboard's).
COLORMAPS = {"turbo": cv2.COLORMAP_TURBO, "viridis": cv2.COLORMAP_VIRIDIS, "inferno": cv2.COLORMAP_INFERNO,
             "jet": cv2.COLORMAP_JET}


def colour_indices(values: np.ndarray, value_range: tuple[float, float] | None = None
                   ) -> tuple[np.ndarray, float, float]:
    """``(uint8 indices, low, high)``: the map scaled linearly from ``low`` (index 0) to ``high``
    (255), rounded, clipped outside; the range defaults to the finite values' minimum and
    maximum. A constant map (or range) is index 0; a NaN is ``low``'s colour."""
    data = np.asarray(values, dtype=np.float64)
    if value_range is None:
        finite = data[np.isfinite(data)]
        low, high = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 0.0)
    else:
        low, high = float(value_range[0]), float(value_range[1])
    if not high > low:
        return np.zeros(data.shape, np.uint8), low, high
    clean = np.nan_to_num(data, nan=low, posinf=high, neginf=low)
    indices = np.rint((clean - low) * (255.0 / (high - low)))
    return np.clip(indices, 0, 255).astype(np.uint8), low, high


def colour_picture(values: np.ndarray, colormap: str = "viridis", value_range: tuple[float, float] | None = None
                   ) -> tuple[np.ndarray, float, float]:
    """``(BGR uint8 picture, low, high)`` of a map in ``colormap`` (see :func:`colour_indices`)."""
    if colormap not in COLORMAPS:
        raise ValueError(f"unknown colour map {colormap!r} (one of {', '.join(COLORMAPS)})")
    indices, low, high = colour_indices(values, value_range)
    return cv2.applyColorMap(indices, COLORMAPS[colormap]), low, high


def colour_ramp(height: int, width: int, colormap: str = "viridis") -> np.ndarray:
    """The colour bar of :func:`colour_picture`: ``height`` rows, the maximum at the top."""
    ramp = np.rint(np.linspace(255, 0, height)).astype(np.uint8)[:, None].repeat(width, axis=1)
    return cv2.applyColorMap(ramp, COLORMAPS[colormap])


def write_atomic(path: str | Path, write: Callable[[BinaryIO], object]) -> Path:
    """Write a file whole or not at all: ``write`` fills a temporary file beside ``path``, which
    replaces ``path`` only once complete and synced; a failure (an exception, a full disk) leaves
    no half-written ``path`` and no temporary file. ``WriteFailed`` (exit 74) when the disk refuses."""
    from edgedsm.frameio.recording import WriteFailed

    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        descriptor, temporary = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".partial", dir=path.parent)
    except OSError as exc:
        raise WriteFailed(f"{path}: cannot be written: {exc.strerror or exc}") from None
    try:
        with os.fdopen(descriptor, "wb") as file:
            write(file)
            file.flush()
            os.fsync(file.fileno())
        os.replace(temporary, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            os.unlink(temporary)
        raise WriteFailed(f"{path}: cannot be written: {exc.strerror or exc}") from None
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(temporary)
        raise
    return path


def _check_frame(frame: np.ndarray) -> np.ndarray:
    if frame.ndim != 2:
        raise ImageIOError(f"expected 2-D monochrome frames, got shape {frame.shape}")
    return frame


def write_stack(path: str | Path, frames: Iterable[np.ndarray], count: int) -> Path:
    """Write ``count`` frames as .npy (streamed to disk), multi-page TIFF, or an image sequence.

    An image sequence is chosen by a ``%d`` pattern (``out/%05d.png``) or an existing directory
    (PNG files). Returns the path written.
    """
    path = Path(path)
    text = str(path)
    if "%" in text or path.is_dir():
        pattern = text if "%" in text else str(path / "frame_%05d.png")
        Path(pattern).parent.mkdir(parents=True, exist_ok=True)
        for index, frame in enumerate(_take(frames, count)):
            _write_image(Path(pattern % index), frame)
        return Path(pattern).parent
    path.parent.mkdir(parents=True, exist_ok=True)
    suffix = path.suffix.lower()
    if suffix == ".npy":
        iterator = _take(frames, count)
        first = next(iterator)
        stack = np.lib.format.open_memmap(path, mode="w+", dtype=first.dtype,
                                          shape=(count, *first.shape))
        stack[0] = first
        for index, frame in enumerate(iterator, start=1):
            stack[index] = frame
        stack.flush()
        del stack
        return path
    if suffix in (".tif", ".tiff"):
        pages = [np.ascontiguousarray(_as_image(f)) for f in _take(frames, count)]
        if not cv2.imwritemulti(text, pages):
            raise ImageIOError(f"{path}: TIFF could not be written")
        return path
    raise ImageIOError(f"{path}: unsupported output {suffix!r} (use .npy, .tif or 'dir/%05d.png')")


def _take(frames: Iterable[np.ndarray], count: int) -> Iterator[np.ndarray]:
    for index, frame in enumerate(frames):
        if index >= count:
            return
        yield _check_frame(frame)


def _as_image(frame: np.ndarray) -> np.ndarray:
    if frame.dtype in (np.uint8, np.uint16):
        return frame
    raise ImageIOError(f"images need uint8 or uint16 frames, got {frame.dtype} (add a [detector] or use .npy)")


def _write_image(path: Path, frame: np.ndarray) -> None:
    if not cv2.imwrite(str(path), _as_image(frame)):
        raise ImageIOError(f"{path}: could not be written")


@dataclass(frozen=True)
class MapAxes:
    """What a picture's axes are when they are not the camera's pixels (a THSP's time and
    position, a co-occurrence matrix's grey levels): each axis's label with its unit and the
    values at its first and last row or column. A picture with axes has no pixel scale bar."""

    x: str
    y: str
    x_range: tuple[float, float]
    y_range: tuple[float, float]


@dataclass(frozen=True)
class MapPicture:
    """A map drawn for a file: the BGR canvas and every text drawn on it (title, colour scale,
    axes or scale bar), so that a test can check what the picture says."""

    canvas: np.ndarray
    texts: tuple[str, ...]


#: The spatial scale bar of a picture in camera pixels (maps of a frame, without MapAxes).
SCALE_BAR_PX = 50


def _number(value: float) -> str:
    return f"{value:.4g}"


def _vertical_text(text: str, height: int, font_scale: float) -> np.ndarray:
    """``text`` written bottom to top on a white strip ``height`` rows tall (a y axis label)."""
    font = cv2.FONT_HERSHEY_SIMPLEX
    width = cv2.getTextSize(text, font, font_scale, 1)[0][0]
    if width + 4 > height:  # a short picture: a smaller font rather than a cut label
        font_scale *= max(height - 4, 1) / width
    (width, text_h), base = cv2.getTextSize(text, font, font_scale, 1)
    strip = np.full((text_h + base + 4, height, 3), 255, np.uint8)
    cv2.putText(strip, text, (max(0, (height - width) // 2), text_h + 2), font, font_scale, (0, 0, 0), 1,
                cv2.LINE_AA)
    return np.ascontiguousarray(np.rot90(strip))


def render_map(values: np.ndarray, title: str = "", value_range: tuple[float, float] | None = None,
               unit: str = "", axes: MapAxes | None = None) -> MapPicture:
    """The picture :func:`save_map_png` writes (viridis, a labelled colour scale): with ``axes``,
    each axis labelled and its end values written; without, a bar of 50 camera pixels."""
    data = np.asarray(values, np.float64)
    if data.ndim != 2:
        raise ImageIOError(f"a map must be 2-D, got shape {data.shape}")
    finite = data[np.isfinite(data)]
    if value_range is None:
        low, high = (np.percentile(finite, [1, 99]) if finite.size else (0.0, 1.0))
    else:
        low, high = value_range
    if not high > low:
        high = low + 1.0
    picture, low, high = colour_picture(data, "viridis", (float(low), float(high)))
    zoom = max(1, math.ceil(384 / max(data.shape)))  # small maps are enlarged to stay legible
    # axes that are not space have no aspect to keep: each is enlarged to at least 256 px on its own
    zoom_y, zoom_x = ((zoom, zoom) if axes is None else
                      (max(1, math.ceil(256 / data.shape[0])), max(1, math.ceil(256 / data.shape[1]))))
    picture = cv2.resize(picture, None, fx=zoom_x, fy=zoom_y, interpolation=cv2.INTER_NEAREST)
    h, w = picture.shape[:2]
    left = 64 if axes is not None else 0  # the y axis: its label and end values
    margin_top, bar_w, label_w = 28, 18, 90
    bottom = 44 if axes is not None else 30
    canvas = np.full((h + margin_top + bottom, left + w + bar_w + label_w + 20, 3), 255, np.uint8)
    canvas[margin_top:margin_top + h, left:left + w] = picture
    texts: list[str] = []
    font, black = cv2.FONT_HERSHEY_SIMPLEX, (0, 0, 0)

    def write(text: str, x: int, y: int, scale: float = 0.4) -> None:
        cv2.putText(canvas, text, (x, y), font, scale, black, 1, cv2.LINE_AA)
        texts.append(text)

    x0 = left + w + 10
    canvas[margin_top:margin_top + h, x0:x0 + bar_w] = colour_ramp(h, bar_w, "viridis")
    for fraction in (0.0, 0.5, 1.0):
        y = margin_top + round((1 - fraction) * (h - 1))
        write(f"{_number(low + fraction * (high - low))}{(' ' + unit) if unit else ''}",
              x0 + bar_w + 4, min(max(y + 4, margin_top + 8), margin_top + h))
    if title:
        write(title, 2, 18, 0.5)
    if axes is not None:
        below = margin_top + h + 14
        first, last = _number(axes.x_range[0]), _number(axes.x_range[1])
        write(first, left, below)
        write(last, left + w - cv2.getTextSize(last, font, 0.4, 1)[0][0], below)
        write(axes.x, max(2, left + (w - cv2.getTextSize(axes.x, font, 0.45, 1)[0][0]) // 2), below + 22, 0.45)
        for value, y in ((axes.y_range[0], margin_top + 10), (axes.y_range[1], margin_top + h)):
            text = _number(value)
            write(text, left - 4 - cv2.getTextSize(text, font, 0.4, 1)[0][0], y)
        label = _vertical_text(axes.y, h, 0.45)
        width = min(label.shape[1], 22)
        canvas[margin_top:margin_top + h, 0:width] = label[:, :width]
        texts.append(axes.y)
    else:
        bar_px = SCALE_BAR_PX * zoom  # spatial scale bar: 50 camera pixels
        if bar_px < w:
            y = margin_top + h + 14
            cv2.line(canvas, (4, y), (4 + bar_px, y), black, 3)
            write(f"{SCALE_BAR_PX} px", 8 + bar_px, y + 5)
    return MapPicture(canvas, tuple(texts))


def save_map_png(path: str | Path, values: np.ndarray, title: str = "",
                 value_range: tuple[float, float] | None = None, unit: str = "",
                 axes: MapAxes | None = None) -> Path:
    """Write :func:`render_map`'s colour-mapped picture of a float map (PNG, or the format of
    ``path``'s suffix) whole or not at all; returns ``path``.

    ``value_range`` fixes the colour scale (default: 1st to 99th percentile) so that several
    maps can share one scale; ``axes`` names axes that are not the camera's pixels (then no
    pixel scale bar is drawn).
    """
    canvas = render_map(values, title, value_range, unit, axes).canvas
    path = Path(path)
    try:
        encoded, data = cv2.imencode(path.suffix or ".png", canvas)
    except cv2.error:
        encoded = False
    if not encoded:
        raise ImageIOError(f"{path}: could not be written (no image format for {path.suffix!r})")
    return write_atomic(path, lambda file: file.write(data.tobytes()))
