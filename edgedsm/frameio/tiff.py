"""Multi-page TIFF and BigTIFF, compressed or not, read page by page with tifffile; and
edgedsm's own recordings (``edgedsm.frameio.recording``), which are such files with a record
per page (sequence number, timestamp, laser state).

A page that cannot be decoded (a truncated or damaged file) is ``ReaderError`` naming the file
and the page, except the last page of an edgedsm recording: a recorder killed while writing
leaves that one incomplete, and it is dropped with a note.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from edgedsm.errors import DataError
from edgedsm.frameio.base import FrameReader, ReaderError, Stamps
from edgedsm.frameio.budget import check_frame
from edgedsm.frameio.recording import is_recording, parse_description

TIFF_SUFFIXES = (".tif", ".tiff", ".btf", ".tf8")
#: TIFF compression schemes that lose information (tifffile's COMPRESSION names) ...
LOSSY_COMPRESSION = {"JPEG", "OJPEG", "JPEG_99", "ALT_JPEG", "JPEG_LOSSY", "JPEG_2000_LOSSY", "APERIO_JP2000_YCBC",
                     "APERIO_JP2000_RGB", "WEBP", "WEBP_DEPRECATED", "JPEGXR", "JPEGXR_NDPI"}
#: ... and those that may or may not (the file does not say which mode wrote it).
MAYBE_LOSSY_COMPRESSION = {"JPEG2000", "JPEGXL", "JPEGXL_DNG", "LERC"}


class _TiffLog(logging.Handler):
    """Keeps what tifffile logs while opening (it logs, not raises, on a damaged page chain)."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage().split("> ", 1)[-1])  # without tifffile's object repr


class TiffReader(FrameReader):
    kind = "tiff"

    def __init__(self, path: Path, channel: str | None = None) -> None:
        super().__init__(path, channel)
        self._tif = None
        try:
            self._open()
        except BaseException:
            self.close()
            raise

    def _open(self) -> None:
        import tifffile

        path = self.path
        tiff_log = _TiffLog()
        logger = logging.getLogger("tifffile")
        logger.addHandler(tiff_log)
        propagate, logger.propagate = logger.propagate, False
        try:
            self._tif = tifffile.TiffFile(path)
            count = len(self._tif.pages)  # walks the page chain (headers only)
        except Exception as exc:  # tifffile's own errors and struct/Value/OS/Index errors of a damaged file
            raise ReaderError(f"{path}: cannot be read as a TIFF: {exc or type(exc).__name__}") from None
        finally:
            logger.removeHandler(tiff_log)
            logger.propagate = propagate
        if count == 0:
            why = tiff_log.messages[0] if tiff_log.messages else "no pages"
            raise ReaderError(f"{path}: cannot be read as a TIFF: {why}")
        first = self._tif.pages.first
        self.recording = is_recording(first.description)
        self._records: list[dict[str, Any]] | None = None
        if self.recording:
            self.kind = "recording"
            self._header = self._record(0, first.description)
        if tiff_log.messages and not self.recording:
            raise ReaderError(f"{path}: damaged or truncated TIFF after {count} pages: {tiff_log.messages[0]}")
        self.count = count
        compression = getattr(first.compression, "name", str(first.compression))
        if compression in LOSSY_COMPRESSION:
            self.lossy = compression
            self.note(f"{path}: pages are {compression}-compressed, a lossy codec: compression artefacts change "
                      f"the speckle statistics (analysed all the same)")
        elif compression in MAYBE_LOSSY_COMPRESSION:
            self.note(f"{path}: pages are {compression}-compressed, which may be lossy (the file does not say): "
                      f"if so, compression artefacts change the speckle statistics")
        image = self._page(0)
        self._settle(image, 1 if image.ndim == 2 else image.shape[2], order="rgb")
        if self.recording:
            self.bits = int(self._header.get("bits") or self.bits or 8)
            self._drop_incomplete_last_page()
            self.dt = self.stamps().interval_s()  # type: ignore[union-attr]
        elif first.bitspersample < 8 * self.dtype.itemsize and self.dtype.kind == "u":
            self.bits = int(first.bitspersample)

    def _record(self, index: int, description: str | None) -> dict[str, Any]:
        try:
            return parse_description(description, f"{self.path} page {index}")
        except DataError as exc:
            raise ReaderError(str(exc)) from None

    def _drop_incomplete_last_page(self) -> None:
        """A recorder killed mid-page leaves the last page broken: drop it, keep the rest."""
        last = (self.count or 1) - 1
        if last == 0:
            return
        try:
            description = self._tif.pages[last].description
        except Exception:  # an unreadable page header: the incomplete page itself
            description = ""
        try:
            if not description:  # its header not written yet: the recorder died in the middle of it
                raise ReaderError("no page header")
            self._page(last)
        except ReaderError as exc:
            self.count = last
            self.note(f"{self.path}: last page incomplete (recorder stopped while writing it?); "
                      f"{last} complete frames kept ({exc})")
            return
        self._record(last, description)  # a complete page with a bad record is a corrupt index

    def _page(self, index: int) -> np.ndarray:
        try:
            page = self._tif.pages[index]
        except Exception as exc:  # a damaged page chain: name the page, no traceback
            raise ReaderError(f"{self.path}: page {index} cannot be read (truncated or damaged file?): "
                              f"{type(exc).__name__}: {exc}") from None
        self._check_page(index, page)
        try:
            image = page.asarray()
            axes = page.axes
        except Exception as exc:  # any decoding failure of damaged data: name the page, no traceback
            raise ReaderError(f"{self.path}: page {index} cannot be decoded (truncated or damaged file?): "
                              f"{type(exc).__name__}: {exc}") from None
        if image.ndim == 3 and axes.startswith("S"):  # planar colour: S, Y, X -> Y, X, S
            image = np.moveaxis(image, 0, -1)
        return image

    def _check_page(self, index: int, page: Any) -> None:
        """The page's size from its tags, checked against the budget before it is decoded (a
        1.9 MB deflate page can claim 45000 x 45000 pixels)."""
        what = f"TIFF page {index} header"
        try:
            dtype = page.dtype
            depth, rows, columns = int(page.imagedepth), int(page.imagelength), int(page.imagewidth)
            samples = int(page.samplesperpixel)
            tile = (int(page.tilelength), int(page.tilewidth)) if page.is_tiled else None
        except Exception as exc:
            raise ReaderError(f"{self.path}: {what} cannot be read: {type(exc).__name__}: {exc}") from None
        if dtype is None:
            raise ReaderError(f"{self.path}: {what}: samples of {page.bitspersample} bits in format "
                              f"{page.sampleformat} are not grey levels")
        if depth != 1:
            raise ReaderError(f"{self.path}: {what} claims a volume {depth} deep, not a 2-D frame")
        check_frame(self.path, (rows, columns, samples), np.dtype(dtype).itemsize, what)
        if tile is not None:
            check_frame(self.path, (*tile, samples), np.dtype(dtype).itemsize, f"{what} (its tiles)")

    def _raw(self, start: int) -> Iterator[tuple[int, np.ndarray]]:
        for index in range(start, self.count or 0):
            yield index, self._page(index)

    def stamps(self) -> Stamps | None:
        """The recording's per-frame records (read once: one page header per frame)."""
        if not self.recording:
            return None
        if self._records is None:
            self._records = [self._header] + [self._record(i, self._tif.pages[i].description)
                                              for i in range(1, self.count or 0)]
        return Stamps(seq=np.array([r["seq"] for r in self._records], np.int64),
                      t_ns=np.array([r["t_ns"] for r in self._records], np.int64),
                      laser=tuple(r["laser"] for r in self._records))

    @property
    def header(self) -> dict[str, Any]:
        """A recording's first-page record (source, codec, bits, settings); {} for other TIFFs."""
        return dict(self._header) if self.recording else {}

    def close(self) -> None:
        if self._tif is not None:
            self._tif.close()
