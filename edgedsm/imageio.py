"""Writing frame stacks and activity-map pictures (OpenCV + numpy).

Frame stacks: ``.npy`` (N, H, W), multi-page ``.tif``/``.tiff`` or a ``printf`` pattern such as
``frames/%05d.png``. Reading any frame source is ``edgedsm.frameio`` (streaming, one layer for
every command); recordings with timestamps are ``edgedsm record`` (``edgedsm.frameio.recording``).
"""

from __future__ import annotations

import contextlib
import math
import os
import tempfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import BinaryIO

import cv2
import numpy as np

from edgedsm.errors import DataError


class ImageIOError(DataError):
    """A frame file could not be read or written (exit code 65: the data, not the program)."""


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


def save_map_png(path: str | Path, values: np.ndarray, title: str = "",
                 value_range: tuple[float, float] | None = None, unit: str = "") -> Path:
    """Colour-mapped picture (viridis) of a float map with a labelled colour scale and a 50-px bar.

    ``value_range`` fixes the colour scale (default: 1st to 99th percentile) so that several
    maps can share one scale.
    """
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
    scaled = np.clip((np.nan_to_num(data, nan=low) - low) / (high - low), 0, 1)
    picture = cv2.applyColorMap((scaled * 255).astype(np.uint8), cv2.COLORMAP_VIRIDIS)
    zoom = max(1, math.ceil(384 / max(data.shape)))  # small maps are enlarged to stay legible
    picture = cv2.resize(picture, None, fx=zoom, fy=zoom, interpolation=cv2.INTER_NEAREST)
    h, w = picture.shape[:2]
    margin_top, bar_w, label_w = 28, 18, 90
    canvas = np.full((h + margin_top + 30, w + bar_w + label_w + 20, 3), 255, np.uint8)
    canvas[margin_top:margin_top + h, 0:w] = picture
    ramp = np.linspace(255, 0, h).astype(np.uint8)[:, None].repeat(bar_w, axis=1)
    x0 = w + 10
    canvas[margin_top:margin_top + h, x0:x0 + bar_w] = cv2.applyColorMap(ramp, cv2.COLORMAP_VIRIDIS)
    font, black = cv2.FONT_HERSHEY_SIMPLEX, (0, 0, 0)
    for fraction in (0.0, 0.5, 1.0):
        y = margin_top + round((1 - fraction) * (h - 1))
        label = f"{low + fraction * (high - low):.4g}{(' ' + unit) if unit else ''}"
        cv2.putText(canvas, label, (x0 + bar_w + 4, min(max(y + 4, margin_top + 8), margin_top + h)),
                    font, 0.4, black, 1, cv2.LINE_AA)
    if title:
        cv2.putText(canvas, title, (2, 18), font, 0.5, black, 1, cv2.LINE_AA)
    bar_px = 50 * zoom  # spatial scale bar: 50 camera pixels
    if bar_px < w:
        y = margin_top + h + 14
        cv2.line(canvas, (4, y), (4 + bar_px, y), black, 3)
        cv2.putText(canvas, "50 px", (8 + bar_px, y + 5), font, 0.4, black, 1, cv2.LINE_AA)
    path = Path(path)
    try:
        encoded, data = cv2.imencode(path.suffix or ".png", canvas)
    except cv2.error:
        encoded = False
    if not encoded:
        raise ImageIOError(f"{path}: could not be written (no image format for {path.suffix!r})")
    return write_atomic(path, lambda file: file.write(data.tobytes()))
