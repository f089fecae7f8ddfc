"""One reading layer for every frame source: ``open_frames(path, channel)`` gives a streaming
``FrameReader`` (count when known, shape, dtype, bits, frame interval, per-frame stamps of a
recording, and the frames one at a time) for

- ``.npy`` stacks (read frame by frame, never memory-mapped: a file changed under it is an error),
- multi-page TIFF and BigTIFF, compressed or not (tifffile, page by page), and edgedsm's own
  recordings (``edgedsm record``: BigTIFF with a record per page),
- image folders and printf patterns (``frames/%05d.png``), in natural numeric order,
- video files (AVI, MP4, MKV, MOV ... through PyAV, by each frame's pixel format; a lossy codec is noted).

``analyze``, ``--timeline``, the ``replay:`` camera and ``probe camera replay:`` all read through
it. What a header claims is checked against one memory budget before anything is allocated or
decoded (``edgedsm.frameio.budget``). Writing recordings: ``edgedsm.frameio.recording.RecordingWriter``.
"""

from __future__ import annotations

from pathlib import Path

from edgedsm.frameio.base import FrameReader, InputMissing, ReaderError, Stamps
from edgedsm.frameio.channels import CHANNELS
from edgedsm.frameio.images import IMAGE_SUFFIXES, ImageSeriesReader
from edgedsm.frameio.npy import NpyReader
from edgedsm.frameio.tiff import TIFF_SUFFIXES, TiffReader
from edgedsm.frameio.video import VIDEO_SUFFIXES, VideoReader

SUPPORTED = ".npy, .tif/.tiff (also BigTIFF and edgedsm recordings), a video (.avi, .mp4, .mkv, .mov), " \
            "an image folder or a pattern such as frames/%05d.png"


def open_frames(path: str | Path, channel: str | None = None) -> FrameReader:
    """The reader for ``path`` (see the module docstring); ``channel`` picks red, green, blue or
    luma of a colour source. ``InputMissing`` (exit 66) when nothing is there, ``ReaderError``
    (exit 65) when it cannot be read as frames."""
    text = str(path)
    path = Path(path)
    if "%" in path.name:
        return ImageSeriesReader(path, channel)
    if path.is_dir():
        return ImageSeriesReader(path, channel)
    if not path.exists():
        raise InputMissing(f"{path}: no such file or directory")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        return NpyReader(path, channel)
    if suffix in TIFF_SUFFIXES:
        return TiffReader(path, channel)
    if suffix in VIDEO_SUFFIXES:
        return VideoReader(path, channel)
    if suffix in IMAGE_SUFFIXES:
        raise ReaderError(f"{text}: a single image is not a series of frames; give its folder or a pattern")
    raise ReaderError(f"{text}: unsupported frame format {suffix!r} (use {SUPPORTED})")


__all__ = ["CHANNELS", "SUPPORTED", "FrameReader", "InputMissing", "ReaderError", "Stamps", "open_frames"]
