"""Video files (AVI, MP4, MKV, MOV ...) decoded frame by frame with OpenCV (its FFmpeg backend).

OpenCV decodes to B, G, R: a grey video gives three equal channels and is read as grey; a
colour one needs a channel. A grey video of more than 8 bits (FFV1 gray16le) is read unconverted,
as uint16. Lossless codecs (raw, FFV1, HuffYUV, Lagarith, PNG ...) give the
frames as recorded; any other codec (MJPG, H.264, MPEG-4 ...) is accepted for analysis with a
note naming its FOURCC, because its artefacts change the speckle statistics.

The frame count is the container's (AVI and MP4 store it; MKV and WebM only a duration, so
their count is unknown). A file that ends before the count it announces is truncated:
``ReaderError`` naming the file, once the last frame has been decoded.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from edgedsm.frameio.base import FrameReader, ReaderError

# FFmpeg's own lines about a damaged stream ("Slice pointer chain broken") would come on top of
# the one line edgedsm says about the file; read when OpenCV first loads FFmpeg. Overridable.
os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")

VIDEO_SUFFIXES = (".avi", ".mp4", ".mkv", ".mov", ".webm", ".m4v", ".mj2")
#: FOURCCs of codecs that keep every pixel ("\0\0\0\0" and "DIB " are raw frames in an AVI).
LOSSLESS_FOURCCS = {"\0\0\0\0", "DIB ", "RAW ", "raw ", "Y800", "Y8  ", "GREY", "Y16 ", "FFV1", "ffv1", "HFYU",
                    "FFVH", "LAGS", "MPNG", "png ", "PNG ", "UYVY", "YUY2", "YUYV", "I420", "IYUV", "RGBA",
                    "BGRA", "RGB ", "BGR ", "r210", "v210", "ULRG", "ULY0", "ULY2", "ULRA", "MAGY", "M8Y0"}
#: Containers whose frame count is an estimate from the duration, not a stored number.
_ESTIMATED_COUNT = (".mkv", ".webm")


def fourcc_text(code: float) -> str:
    value = int(code)
    return "".join(chr((value >> (8 * i)) & 0xFF) for i in range(4))


def shown_fourcc(fourcc: str) -> str:
    return "raw (no FOURCC)" if fourcc == "\0\0\0\0" else repr(fourcc.strip("\0 ") or fourcc)


def _deep_capture(path: Path) -> tuple[cv2.VideoCapture, np.ndarray] | None:
    """A capture and its first frame when the video is grey with more than 8 bits (FFV1 gray16le):
    OpenCV's default conversion to B, G, R would cut it to 8 bits, so it is read unconverted.
    None for every other video (OpenCV's warnings about unconverted colour formats silenced)."""
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    try:
        capture = cv2.VideoCapture(str(path), cv2.CAP_FFMPEG, [cv2.CAP_PROP_CONVERT_RGB, 0])
        ok, image = capture.read() if capture.isOpened() else (False, None)
    finally:
        cv2.utils.logging.setLogLevel(level)
    if ok and image is not None and image.ndim == 2 and image.dtype == np.uint16:
        return capture, image
    capture.release()
    return None


class VideoReader(FrameReader):
    kind = "video"

    def __init__(self, path: Path, channel: str | None = None) -> None:
        super().__init__(path, channel)
        deep = _deep_capture(path)
        capture = deep[0] if deep is not None else cv2.VideoCapture(str(path))
        if not capture.isOpened():
            capture.release()
            raise ReaderError(f"{path}: cannot be opened as a video (damaged or truncated file, or a codec "
                              f"this OpenCV build lacks)")
        self._capture = capture
        try:
            self._inspect(deep[1] if deep is not None else None)
        except BaseException:
            self.close()
            raise

    def _inspect(self, first: np.ndarray | None) -> None:
        path, capture = self.path, self._capture
        self.fourcc = fourcc_text(capture.get(cv2.CAP_PROP_FOURCC))
        fps = capture.get(cv2.CAP_PROP_FPS)
        self.dt = 1.0 / fps if fps and fps > 0 else None
        announced = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
        self._announced = announced if announced > 0 and path.suffix.lower() not in _ESTIMATED_COUNT else None
        self.count = self._announced
        self._position = 0
        if first is None:
            ok, first = capture.read()
            first = first if ok else None
        if first is None:
            raise ReaderError(f"{path}: no frame can be decoded (empty, damaged or truncated video)")
        self._first: np.ndarray | None = first
        self._settle(first, 1 if first.ndim == 2 else first.shape[2], order="bgr")
        if self.fourcc not in LOSSLESS_FOURCCS:
            self.lossy = self.fourcc
            self.note(f"{path}: codec {shown_fourcc(self.fourcc)} is lossy: compression artefacts change the "
                      f"speckle statistics (analysed all the same; record with a lossless codec such as FFV1)")

    def _read(self) -> np.ndarray | None:
        if self._first is not None and self._position == 0:
            image, self._first = self._first, None
        else:
            ok, image = self._capture.read()
            if not ok or image is None:
                return None
        self._position += 1
        return image

    def _skip_to(self, start: int) -> None:
        """Decode forward to frame ``start`` (seeking in a compressed stream is not exact)."""
        if start < self._position:
            self._capture.set(cv2.CAP_PROP_POS_FRAMES, 0)
            self._position, self._first = 0, None
        while self._position < start:
            if self._first is not None and self._position == 0:
                self._first = None
            elif not self._capture.grab():
                self._truncated(self._position)
                raise ReaderError(f"{self.path}: has {self._position} frames; frame {start} does not exist")
            self._position += 1

    def _truncated(self, decoded: int) -> None:
        if self._announced is not None and decoded < self._announced:
            raise ReaderError(f"{self.path}: ends after {decoded} of the {self._announced} frames its header "
                              f"announces (truncated or damaged video)")

    def _raw(self, start: int) -> Iterator[tuple[int, np.ndarray]]:
        self._skip_to(start)
        while True:
            index = self._position
            image = self._read()
            if image is None:
                self._truncated(index)
                if self.count is None:
                    self.count = index
                return
            yield index, image

    def close(self) -> None:
        capture = getattr(self, "_capture", None)
        if capture is not None:
            capture.release()
            self._capture = None
