"""A numbered image series: a folder of images, or a ``printf`` pattern such as ``frames/%05d.png``.

Order is natural numeric order (``img_2`` before ``img_10``): frames sorted by plain name order
(img_1, img_10, img_100, img_2 ...) would give maps computed from shuffled frames, silently.
Every file's header is read at open (sizes only, no pixels: ``edgedsm.frameio.budget.image_size``),
so one odd-sized image, or one whose header claims more than the memory budget, is named before
anything is decoded; pixels are decoded one frame at a time with OpenCV (colour comes as B, G, R),
each file's header checked again just before (OpenCV has no header-only read, and allocates
what a header claims). A pattern's missing numbers are noted.
"""

from __future__ import annotations

import contextlib
import os
import re
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from edgedsm.frameio.base import FrameReader, InputMissing, ReaderError, describe_shape
from edgedsm.frameio.budget import check_image

IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".bmp", ".jpg", ".jpeg", ".pgm", ".ppm", ".pnm")
LOSSY_SUFFIXES = (".jpg", ".jpeg")
_DIGITS = re.compile(r"(\d+)")


@contextlib.contextmanager
def _opencv_silent() -> Iterator[None]:
    """OpenCV logs a damaged file's decoding errors on stderr, several lines each: silenced
    while decoding (the caller says what went wrong, in one line)."""
    logging = cv2.utils.logging
    level = logging.getLogLevel()
    logging.setLogLevel(logging.LOG_LEVEL_SILENT)
    try:
        yield
    finally:
        logging.setLogLevel(level)


def _jpeg_complete(path: Path) -> bool:
    """Whether a JPEG's end-of-image marker is there (libjpeg decodes a truncated file with a
    message on stderr and grey where the data ends, rather than failing)."""
    with open(path, "rb") as file:
        file.seek(max(0, os.fstat(file.fileno()).st_size - 4096))
        return b"\xff\xd9" in file.read()


def decode_image(path: Path, flags: int = cv2.IMREAD_UNCHANGED, what: str = "header") -> np.ndarray | None:
    """One image file decoded by OpenCV once its header passed the memory budget (``BudgetError``
    naming the file and the claim otherwise); None when it cannot be decoded (damaged, truncated),
    with nothing printed."""
    size = check_image(path, what)  # before OpenCV allocates what the header claims
    if size.format == "JPEG" and not _jpeg_complete(path):
        return None
    with _opencv_silent():
        return cv2.imread(str(path), flags)


def natural_key(name: str) -> tuple:
    """Sort key putting 'img_2' before 'img_10': digit runs compare as numbers."""
    return tuple((0, int(part), part) if part.isdigit() else (1, 0, part.lower())
                 for part in _DIGITS.split(name) if part)


def folder_files(folder: Path) -> list[Path]:
    """The images of a folder, in natural numeric order."""
    files = [p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES]
    return sorted(files, key=lambda p: natural_key(p.name))


def pattern_files(pattern: str) -> tuple[list[Path], list[int]]:
    """Files matching a printf pattern (one ``%d``, ``%05d`` ...), in numeric order, and the
    numbers missing between the first and the last."""
    parent, name = Path(pattern).parent, Path(pattern).name
    match = re.fullmatch(r"(.*?)%(0?)(\d*)d(.*)", name)
    if match is None or "%" in match.group(1) + match.group(4):
        raise ReaderError(f"{pattern}: a frame pattern needs exactly one %d (e.g. frames/%05d.png)")
    head, zero, width, tail = match.groups()
    digits = rf"\d{{{width},}}" if zero and width else r"\d+"
    regex = re.compile(re.escape(head) + f"({digits})" + re.escape(tail))
    if not parent.is_dir():
        raise InputMissing(f"{parent}: no such directory (from the pattern {pattern})")
    numbered = sorted((int(m.group(1)), p) for p in parent.iterdir()
                      if (m := regex.fullmatch(p.name)) is not None and p.is_file())
    numbers = [n for n, _ in numbered]
    missing = sorted(set(range(numbers[0], numbers[-1] + 1)) - set(numbers)) if numbers else []
    return [p for _, p in numbered], missing


class ImageSeriesReader(FrameReader):
    kind = "image series"

    def __init__(self, path: Path, channel: str | None = None) -> None:
        super().__init__(path, channel)
        text = str(path)
        try:
            self._list(path, text)
        except OSError as exc:
            raise ReaderError(f"{path}: cannot be listed: {exc.strerror or exc}") from None
        if not self.files:
            raise ReaderError(f"{path}: no images ({', '.join(s.lstrip('.') for s in IMAGE_SUFFIXES)})")
        self.count = len(self.files)
        self.kind = "pattern" if "%" in text else "folder"
        first = self._decode(0)
        self._settle(first, 1 if first.ndim == 2 else first.shape[2], order="bgr")
        self._check_headers()
        if any(p.suffix.lower() in LOSSY_SUFFIXES for p in self.files):
            self.lossy = "JPEG"
            self.note(f"{path}: JPEG images are lossy: compression artefacts change the speckle "
                      f"statistics (analysed all the same)")

    def _list(self, path: Path, text: str) -> None:
        if "%" in text:
            self.files, missing = pattern_files(text)
            if missing:
                shown = ", ".join(str(n) for n in missing[:10]) + (" ..." if len(missing) > 10 else "")
                self.note(f"{path}: {len(missing)} numbers missing in the series ({shown}); the frames "
                          f"around them are read as consecutive")
        else:
            self.files = folder_files(path)

    def _check_headers(self) -> None:
        """Name the first image whose size differs from the first one's, before any pixel is used."""
        for file in self.files[1:]:
            size = check_image(file)
            if size.shape != self.shape:
                raise ReaderError(f"{file}: {describe_shape(size.shape)} frame among "
                                  f"{describe_shape(self.shape)} ones; a recording keeps one frame size")

    def _decode(self, index: int) -> np.ndarray:
        file = self.files[index]
        image = decode_image(file)
        if image is None:
            raise ReaderError(f"{file}: cannot be read as an image (frame {index} of {self.path})")
        return image

    def _raw(self, start: int) -> Iterator[tuple[int, np.ndarray]]:
        for index in range(start, len(self.files)):
            yield index, self._decode(index)

    def _checked(self, index: int, image: np.ndarray) -> np.ndarray:
        try:
            return super()._checked(index, image)
        except ReaderError as exc:  # name the file, not the folder
            raise ReaderError(f"{self.files[index]}: {str(exc).split(': ', 1)[1]}") from None
