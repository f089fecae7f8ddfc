"""The one memory-budget rule every reader applies to what a file's header claims, before a byte
of pixels is allocated or decoded; and the header-only size of an image file.

A header is a claim, not a fact: a 6-byte file can say it holds 45000 x 45000 pixels, and a
1.9 MB deflate TIFF really does decode to 2 GB. So a frame is refused (``BudgetError``, exit
65, one line naming the file and the claim) when

- a dimension is zero or negative,
- one frame has more than ``MAX_FRAME_PIXELS`` pixels (2^28: a 16384 x 16384 sensor; the largest
  scientific cameras have about 2^27), or
- an allocation (one frame, or a batch window of frames) would take more than
  ``MEMORY_FRACTION`` of the memory the machine has available now (``MemAvailable``).

``image_size(path)`` reads the size of a PNG, BMP, JPEG, PNM or TIFF from its header alone
(a few hundred bytes; TIFF through tifffile's tag reader), so an image folder or a mask is checked
before OpenCV decodes anything (OpenCV has no header-only read).
"""

from __future__ import annotations

import logging
import math
import os
import re
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from edgedsm.frameio.errors import ReaderError

#: Pixels one frame may have (rows x columns; colour samples are counted in its bytes).
MAX_FRAME_PIXELS = 2 ** 28
#: The share of the memory available now that one allocation may take.
MEMORY_FRACTION = 0.5
_FALLBACK_AVAILABLE = 2 ** 31  # where /proc/meminfo cannot be read: assume 2 GiB


class BudgetError(ReaderError):
    """A header claims a frame or a stack that is impossible or too large (exit code 65)."""


def available_bytes() -> int:
    """Memory available to a new allocation now (Linux ``MemAvailable``)."""
    try:
        with open("/proc/meminfo", encoding="ascii") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return _FALLBACK_AVAILABLE


def _gib(nbytes: float) -> str:
    return f"{nbytes / 2 ** 30:.3g} GiB" if nbytes >= 2 ** 30 else f"{nbytes / 2 ** 20:.3g} MiB"


def check_bytes(path: Path | str, what: str, nbytes: int) -> None:
    """Refuse one allocation of ``nbytes`` larger than the budget; ``what`` says what it is."""
    limit = int(MEMORY_FRACTION * available_bytes())
    if nbytes > limit:
        raise BudgetError(f"{path}: {what} would take {_gib(nbytes)}, more than the {_gib(limit)} "
                          f"allowed ({MEMORY_FRACTION:.0%} of the memory available now)")


def check_frame(path: Path | str, shape: tuple[int, ...], itemsize: int, what: str = "header") -> int:
    """Check one frame's ``shape`` (rows, columns[, samples]) of ``itemsize``-byte samples as a
    ``what`` claims it; its size in bytes when it fits the budget, else ``BudgetError``."""
    dims = tuple(int(n) for n in shape)
    shown = " x ".join(str(n) for n in dims)
    if len(dims) < 2 or any(n <= 0 for n in dims) or itemsize <= 0:
        raise BudgetError(f"{path}: the {what} claims frames of {shown} pixels"
                          f"{'' if itemsize > 0 else f' of {itemsize} bytes'}: not a frame size")
    pixels = dims[0] * dims[1]
    if pixels > MAX_FRAME_PIXELS:
        raise BudgetError(f"{path}: the {what} claims frames of {shown} = {pixels:,} pixels, more than the "
                          f"{MAX_FRAME_PIXELS:,} (2^{int(math.log2(MAX_FRAME_PIXELS))}) a frame may have")
    nbytes = math.prod(dims) * itemsize
    check_bytes(path, f"a frame of {shown} pixels as the {what} claims", nbytes)
    return nbytes


def check_count(path: Path | str, count: int, what: str = "header") -> None:
    """Refuse a frame count of zero or less."""
    if count <= 0:
        raise BudgetError(f"{path}: the {what} claims {count} frames: it holds no frames")


@dataclass(frozen=True)
class ImageSize:
    """An image's size as its header tells: rows, columns, samples per pixel, bytes per sample."""

    rows: int
    columns: int
    samples: int
    itemsize: int
    format: str

    @property
    def shape(self) -> tuple[int, int]:
        return self.rows, self.columns


def _png(head: bytes) -> ImageSize | None:
    if len(head) < 26 or head[12:16] != b"IHDR":
        return None
    width, height, depth, colour = struct.unpack(">IIBB", head[16:26])
    samples = {0: 1, 2: 3, 3: 3, 4: 2, 6: 4}.get(colour, 4)
    return ImageSize(height, width, samples, 2 if depth == 16 else 1, "PNG")


def _bmp(head: bytes) -> ImageSize | None:
    if len(head) < 26:
        return None
    (header_size,) = struct.unpack("<I", head[14:18])
    if header_size == 12:
        width, height, _, bits = struct.unpack("<hhHH", head[18:26])
    elif len(head) >= 30:
        width, height, _, bits = struct.unpack("<iiHH", head[18:30])
    else:
        return None
    return ImageSize(abs(height), width, 4 if bits == 32 else 3, 1, "BMP")


def _jpeg(head: bytes, path: Path) -> ImageSize | None:
    with open(path, "rb") as file:  # the SOF marker may come after large EXIF/ICC segments
        file.seek(2)
        for _ in range(1000):
            marker = file.read(4)
            if len(marker) < 4 or marker[0] != 0xFF:
                return None
            kind, length = marker[1], struct.unpack(">H", marker[2:4])[0]
            if 0xC0 <= kind <= 0xCF and kind not in (0xC4, 0xC8, 0xCC):
                frame = file.read(6)
                if len(frame) < 6:
                    return None
                precision, height, width, samples = struct.unpack(">BHHB", frame)
                return ImageSize(height, width, samples, 2 if precision > 8 else 1, "JPEG")
            if length < 2:
                return None
            file.seek(length - 2, os.SEEK_CUR)
    return None


_PNM = re.compile(rb"P([1-7])(?:\s|#[^\n]*\n)+(\d+)(?:\s|#[^\n]*\n)+(\d+)(?:(?:\s|#[^\n]*\n)+(\d+))?")


def _pnm(head: bytes) -> ImageSize | None:
    match = _PNM.match(head)
    if match is None or match.group(1) == b"7":
        return None
    kind, width, height = int(match.group(1)), int(match.group(2)), int(match.group(3))
    maxval = int(match.group(4) or 1) if kind not in (1, 4) else 1
    return ImageSize(height, width, 3 if kind in (3, 6) else 1, 2 if maxval > 255 else 1, "PNM")


def _tiff(path: Path) -> ImageSize | None:
    import tifffile

    logger = logging.getLogger("tifffile")  # it logs a damaged page chain, then says there is none
    propagate, logger.propagate = logger.propagate, False
    quiet = logging.NullHandler()
    logger.addHandler(quiet)
    try:
        with tifffile.TiffFile(path) as tif:
            page = tif.pages.first
            samples = int(page.samplesperpixel)
            return ImageSize(int(page.imagelength), int(page.imagewidth), samples,
                             max(1, int(np.dtype(page.dtype).itemsize) if page.dtype is not None else 1), "TIFF")
    except Exception:  # any damaged header: not an image we can size
        return None
    finally:
        logger.removeHandler(quiet)
        logger.propagate = propagate


def image_size(path: Path) -> ImageSize | None:
    """The size an image file's header claims (PNG, BMP, JPEG, PNM, TIFF by content, not by
    name), reading no pixels; None when the header is not one of these or is damaged."""
    try:
        with open(path, "rb") as file:
            head = file.read(512)
        if head.startswith(b"\x89PNG\r\n\x1a\n"):
            return _png(head)
        if head.startswith(b"BM"):
            return _bmp(head)
        if head.startswith(b"\xff\xd8"):
            return _jpeg(head, path)
        if head[:1] == b"P" and head[1:2] in b"123456":
            return _pnm(head)
    except (OSError, struct.error, ValueError):
        return None
    if head[:4] in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+"):
        return _tiff(path)
    return None


def check_image(path: Path, what: str = "header") -> ImageSize:
    """An image file's size from its header, checked against the budget before OpenCV decodes
    it; ``BudgetError`` when the header is unknown, damaged or claims too much."""
    size = image_size(path)
    if size is None:
        raise BudgetError(f"{path}: cannot be read as an image: its header is not that of a PNG, BMP, JPEG, "
                          f"PNM or TIFF, or is damaged")
    check_frame(path, (size.rows, size.columns, size.samples), size.itemsize, f"{size.format} {what}")
    return size
