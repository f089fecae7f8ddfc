"""edgedsm's own recordings: a BigTIFF of one page per frame, each page carrying its frame's
sequence number, timestamp and laser state.

Format (version 1), chosen so that any TIFF tool opens it and a killed recorder leaves a
readable file:

- BigTIFF (no 4 GiB limit), one page per frame, grey uint8 or uint16 as the camera gave it
  (10/12-bit data stay in uint16, unscaled), compressed losslessly (``CODECS``; the default
  zstd level 1 was chosen by measurement: docs/recording.md);
- each page's ImageDescription (TIFF tag 270) is a one-line JSON object
  ``{"seq": 17, "t_ns": 1712345678901234567, "laser": "on"}``; the first page's also holds
  ``"edgedsm_recording": 1`` (the format version), ``"bits"`` (significant bits) and
  ``"source"`` (the camera URI) and whatever else the recorder adds (camera settings);
- pages are appended one by one through an unbuffered file: each frame is in the operating
  system's hands when ``write`` returns, so a recorder killed by SIGKILL leaves every complete
  page readable (the page being written when it died is dropped by the reader, with a note).

The timestamps sit in the page they describe (no sidecar file to lose or to get out of step).
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from types import TracebackType
from typing import Any, Self

import numpy as np

from edgedsm.errors import DataError, EdgedsmError
from edgedsm.frameio.base import describe_shape
from edgedsm.frames import Frame

FORMAT_KEY = "edgedsm_recording"
FORMAT_VERSION = 1
#: Lossless codecs a recording may use: name -> (tifffile compression, its arguments).
CODECS: dict[str, tuple[str | None, dict[str, int]]] = {
    "zstd": ("zstd", {"level": 1}),
    "deflate": ("zlib", {"level": 1}),
    "lzw": ("lzw", {}),
    "none": (None, {}),
}
DEFAULT_CODEC = "zstd"
LASER_STATES = ("on", "off", "unknown", "none")


class WriteFailed(EdgedsmError):
    """The recording could not be written (disk full, file too large, I/O error): exit code 74
    (EX_IOERR). The frames written before stay readable."""

    exit_code = 74
    kind = "write failed"


class OutputExists(EdgedsmError):
    """The output file exists already (exit code 73, EX_CANTCREAT): recordings are not overwritten."""

    exit_code = 73
    kind = "output exists"


def page_description(seq: int, t_ns: int, laser: str, header: dict[str, Any] | None = None) -> str:
    """The JSON a page carries (the first page also the recording's ``header``)."""
    if laser not in LASER_STATES:
        raise ValueError(f"laser state must be one of {LASER_STATES}, not {laser!r}")
    record: dict[str, Any] = {FORMAT_KEY: FORMAT_VERSION, **header} if header is not None else {}
    record.update(seq=int(seq), t_ns=int(t_ns), laser=laser)
    return json.dumps(record, separators=(",", ":"), ensure_ascii=True)


def parse_description(text: str | None, where: str) -> dict[str, Any]:
    """A page's record; ``DataError`` naming ``where`` when it is not one."""
    try:
        record = json.loads(text or "")
    except ValueError:
        record = None
    if (not isinstance(record, dict) or not isinstance(record.get("seq"), int)
            or not isinstance(record.get("t_ns"), int) or record.get("laser") not in LASER_STATES):
        shown = (text or "")[:60]
        raise DataError(f"{where}: the recording index is corrupt (page description {shown!r} is not "
                        f"{{seq, t_ns, laser}})")
    return record


def is_recording(first_description: str | None) -> bool:
    """True when a TIFF's first page description marks an edgedsm recording."""
    return bool(first_description) and f'"{FORMAT_KEY}"' in first_description[:200]  # type: ignore[index]


class RecordingWriter:
    """Appends frames to a new recording (see the module docstring). Use as a context manager."""

    def __init__(self, path: str | Path, *, codec: str = DEFAULT_CODEC, source: str = "",
                 header: dict[str, Any] | None = None) -> None:
        import tifffile

        if codec not in CODECS:
            raise DataError(f"unknown recording codec {codec!r}: choose one of {', '.join(CODECS)}")
        self.path = Path(path)
        self.codec = codec
        self.header = {"source": source, "codec": codec, **(header or {})}
        self.count = 0
        self._shape: tuple[int, ...] | None = None
        self._dtype: np.dtype | None = None
        try:
            self._file = open(self.path, "xb", buffering=0)  # noqa: SIM115 (closed by close())
        except FileExistsError:
            raise OutputExists(f"{self.path} exists; recordings are never overwritten (choose another name "
                               f"or remove it)") from None
        except OSError as exc:
            raise DataError(f"{self.path}: cannot be created: {exc.strerror or exc}") from None
        self._writer = tifffile.TiffWriter(self._file, bigtiff=True)

    def write(self, frame: Frame, laser: str = "none") -> None:
        """Append one frame as one page; it is in the file when this returns."""
        pixels = frame.pixels
        if pixels.ndim != 2 or pixels.dtype not in (np.uint8, np.uint16):
            raise DataError(f"{self.path}: a recording takes 2-D uint8 or uint16 frames, not {pixels.dtype} "
                            f"{pixels.shape}")
        if self._shape is None:
            self._shape, self._dtype = pixels.shape, pixels.dtype
            description = page_description(frame.seq, frame.t_ns, laser, {**self.header, "bits": frame.bits})
        else:
            if pixels.shape != self._shape or pixels.dtype != self._dtype:
                raise DataError(f"{self.path}: frame {frame.seq} is {describe_shape(pixels.shape)} {pixels.dtype} "
                                f"after {describe_shape(self._shape)} {self._dtype} ones")
            description = page_description(frame.seq, frame.t_ns, laser)
        compression, arguments = CODECS[self.codec]
        try:
            self._writer.write(pixels, description=description, metadata=None, compression=compression,
                               compressionargs=arguments or None, contiguous=False)
        except OSError as exc:
            raise WriteFailed(f"{self.path}: frame {frame.seq} could not be written: {exc.strerror or exc}") from None
        self.count += 1

    def close(self) -> None:
        """Finish the file (safe to call twice); an empty recording is removed."""
        if self._file.closed:
            return
        try:
            self._writer.close()
        except OSError as exc:
            raise WriteFailed(f"{self.path}: could not be finished: {exc.strerror or exc}") from None
        finally:
            self._file.close()
            if self.count == 0:
                os.unlink(self.path)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
