"""Replay of recorded frames as a camera: an image folder, a multi-page TIFF, a video, a .npy stack.

Pacing: ``rate`` frames per second, the recording's own interval where it has one
(``rate="recorded"``: a video's frame rate, or the ``dt`` given), or ``rate=0`` for as fast
as possible. ``loop`` starts again at the end; otherwise ``frames()`` simply ends with the recording.

A recording that cannot be used (not readable as frames, frames that change size, a pixel type
other than uint8/uint16) raises ``DataError`` naming the file (exit code 65).
"""

from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np

from edgedsm.devices.camera.base import Camera, EndOfStream, pace
from edgedsm.errors import DataError, DeviceError
from edgedsm.frames import Frame
from edgedsm.imageio import IMAGE_SUFFIXES, ImageIOError, read_stack

VIDEO_SUFFIXES = (".avi", ".mp4", ".mkv", ".mov")


class ReplayCamera(Camera):
    """Frames from a file or folder, paced like a camera."""

    kind = "replay"

    def __init__(self, path: str | Path, rate: float | str = 0.0, dt: float | None = None,
                 loop: bool = False, bits: int | None = None) -> None:
        super().__init__(f"replay of {path}")
        self.path = Path(path)
        if isinstance(rate, str) and rate != "recorded":
            raise DeviceError(f"rate must be frames/s, 0 (as fast as possible) or 'recorded', not {rate!r}")
        if not isinstance(rate, str) and rate < 0:
            raise DeviceError("rate must be >= 0")
        self.rate = rate
        self.dt = dt
        self.loop = loop
        self._bits = bits
        self._stack: np.ndarray | None = None
        self._video: cv2.VideoCapture | None = None
        self._index = 0
        self._seq = 0
        self._interval = 0.0
        self._due = 0.0
        self._frame_shape: tuple[int, ...] | None = None

    def _do_open(self) -> None:
        if not self.path.exists():
            raise DeviceError(f"{self.path}: no such file or directory")
        recorded_dt = self.dt
        if self.path.suffix.lower() in VIDEO_SUFFIXES:
            video = cv2.VideoCapture(str(self.path))
            if not video.isOpened():
                raise DeviceError(f"{self.path}: cannot be opened as a video")
            self._video = video
            fps = video.get(cv2.CAP_PROP_FPS)
            if recorded_dt is None and fps > 0:
                recorded_dt = 1.0 / fps
        else:
            self._stack = _read_recording(self.path)
            if self._stack.dtype not in (np.uint8, np.uint16):
                raise DataError(f"{self.path}: frames must be uint8 or uint16, not {self._stack.dtype}")
        if self.rate == "recorded":
            if recorded_dt is None:
                raise DeviceError(f"{self.path}: the recording has no frame interval; give dt or a rate")
            self._interval = recorded_dt
        else:
            self._interval = 0.0 if self.rate == 0 else 1.0 / float(self.rate)
        self._timestamp_dt = recorded_dt if recorded_dt is not None else (self._interval or None)

    @property
    def paced(self) -> bool:
        return self.rate != 0  # "recorded" or a rate: paced; 0: as fast as the consumer takes them

    def _do_close(self) -> None:
        if self._video is not None:
            self._video.release()
            self._video = None
        self._stack = None

    def _do_start(self) -> None:
        self._due = 0.0

    @property
    def frame_count(self) -> int | None:
        if self._stack is not None:
            return int(self._stack.shape[0])
        if self._video is not None:
            return int(self._video.get(cv2.CAP_PROP_FRAME_COUNT))
        return None

    def _next_pixels(self) -> np.ndarray | None:
        if self._stack is not None:
            if self._index >= self._stack.shape[0]:
                return None
            pixels = np.ascontiguousarray(self._stack[self._index])
        else:
            assert self._video is not None
            ok, image = self._video.read()
            if not ok:
                return None
            pixels = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        self._index += 1
        return pixels

    def _rewind(self) -> None:
        self._index = 0
        if self._video is not None:
            self._video.set(cv2.CAP_PROP_POS_FRAMES, 0)

    def _do_grab(self, timeout_s: float) -> Frame | None:
        pixels = self._next_pixels()
        if pixels is None and self.loop and self._index > 0:
            self._rewind()
            pixels = self._next_pixels()
        if pixels is None:
            raise EndOfStream(f"{self.description}: end of recording after {self._index} frames")
        if pixels.ndim != 2:
            self._dropped("invalid")
            return None
        if self._frame_shape is None:
            self._frame_shape = pixels.shape
        elif pixels.shape != self._frame_shape:
            raise DataError(f"{self.path}: frame {self._index - 1} is a {_size(pixels.shape)} frame after "
                            f"{_size(self._frame_shape)} ones; a recording keeps one frame size")
        if self._interval > 0:
            self._due = pace(self._due, self._interval)
        seq = self._seq
        self._seq += 1
        bits = self._bits or (8 if pixels.dtype == np.uint8 else 16)
        t_ns = round(seq * self._timestamp_dt * 1e9) if self._timestamp_dt else time.monotonic_ns()
        return Frame(pixels, seq, t_ns, bits)

    def _do_set_frame_interval(self, seconds: float) -> float:
        self._interval = seconds
        return seconds


def _read_recording(path: Path) -> np.ndarray:
    """The (N, H, W) stack of a recording; DataError names the file that spoils it."""
    try:
        return read_stack(path)
    except ImageIOError as exc:
        raise DataError(str(exc)) from None
    except ValueError:
        # np.stack of a folder whose images differ in size: find the first odd one out
        if not path.is_dir():
            raise DataError(f"{path}: frames of different sizes; a recording keeps one frame size") from None
        first: tuple[int, ...] | None = None
        for file in sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES):
            image = cv2.imread(str(file), cv2.IMREAD_UNCHANGED)
            if image is None:
                continue
            if first is None:
                first = image.shape
            elif image.shape != first:
                raise DataError(f"{file}: {_size(image.shape)} frame among {_size(first)} ones; "
                                f"a recording keeps one frame size") from None
        raise DataError(f"{path}: frames of different sizes; a recording keeps one frame size") from None


def _size(shape: tuple[int, ...]) -> str:
    return "x".join(str(n) for n in shape[:2])


def first_frame_shape(path: Path) -> tuple[int, int] | None:
    """(rows, columns) of a recording's first frame, reading only that frame; None when it
    cannot be read (opening the recording will then say why)."""
    try:
        if path.is_dir():
            files = sorted(p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
            image = cv2.imread(str(files[0]), cv2.IMREAD_UNCHANGED) if files else None
        elif path.suffix.lower() == ".npy":
            stack = np.load(path, mmap_mode="r", allow_pickle=False)
            return (int(stack.shape[1]), int(stack.shape[2])) if stack.ndim == 3 else None
        elif path.suffix.lower() in VIDEO_SUFFIXES:
            video = cv2.VideoCapture(str(path))
            ok, image = video.read()
            video.release()
            image = image if ok else None
        else:
            image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)  # a TIFF's first page
    except (OSError, ValueError):
        return None
    return (int(image.shape[0]), int(image.shape[1])) if image is not None else None
