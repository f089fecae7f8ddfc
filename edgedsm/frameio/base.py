"""The contract every frame reader keeps: what the source is, and its frames one at a time.

A reader is opened on a path (``edgedsm.frameio.open_frames``), tells what it knows before any
frame is decoded (count when known, shape, dtype, significant bits, frame interval, whether
the source is colour) and then yields 2-D frames one by one: nothing holds more than one frame
unless the caller keeps them (``window`` stacks a stretch of them on purpose). Colour sources
give the channel chosen (``edgedsm.frameio.channels``); a colour source without a channel is
refused at open.

Every problem with the data is a ``ReaderError`` (exit code 65) naming the file, a missing
input ``InputMissing`` (66); neither ever lets a library's exception or traceback through.
"""

from __future__ import annotations

import abc
import logging
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Self

import numpy as np

from edgedsm.frameio.budget import check_bytes
from edgedsm.frameio.channels import CHANNELS, select_channel
from edgedsm.frameio.errors import InputMissing, ReaderError

log = logging.getLogger(__name__)
__all__ = ["FrameReader", "InputMissing", "ReaderError", "Stamps", "describe_shape"]


@dataclass(frozen=True)
class Stamps:
    """What a recording kept beside each frame: ``seq`` camera frame numbers, ``t_ns``
    acquisition times (ns, the camera's clock), ``laser`` the laser's state ("on", "off",
    "unknown", or "none" without a relay). One entry per frame, in file order."""

    seq: np.ndarray
    t_ns: np.ndarray
    laser: tuple[str, ...]

    def interval_s(self) -> float | None:
        """The median frame interval in seconds (None for fewer than two frames)."""
        if len(self.t_ns) < 2:
            return None
        step = float(np.median(np.diff(self.t_ns.astype(np.float64)))) / 1e9
        return step if step > 0 else None


def _grey(image: np.ndarray) -> bool:
    """True when a colour image's colour channels are all equal (grey stored as colour)."""
    return bool(np.array_equal(image[:, :, 0], image[:, :, 1]) and np.array_equal(image[:, :, 0], image[:, :, 2]))


def describe_shape(shape: tuple[int, ...]) -> str:
    """'rows x columns' as messages show a frame size."""
    return "x".join(str(n) for n in shape[:2])


class FrameReader(abc.ABC):
    """A source of 2-D frames (see the module docstring). Use as a context manager."""

    #: What kind of source it is, for messages ("npy", "tiff", "folder", "video", "recording").
    kind = "frames"

    def __init__(self, path: Path, channel: str | None) -> None:
        if channel is not None and channel not in CHANNELS:
            raise ReaderError(f"{path}: unknown channel {channel!r}: choose one of {', '.join(CHANNELS)}")
        self.path = path
        self.channel = channel
        self.count: int | None = None  # frames, when the source says (some videos do not)
        self.shape: tuple[int, int] = (0, 0)  # rows, columns of every frame
        self.dtype: np.dtype = np.dtype(np.uint8)
        self.bits: int | None = None  # significant bits per pixel (None: floating point)
        self.dt: float | None = None  # frame interval in seconds, when the source has one
        self.colour_order: str | None = None  # "rgb" / "bgr" for a colour source, None for monochrome
        self.lossy: str | None = None  # a lossy codec's name, when the source has one
        self.notes: list[str] = []  # warnings for the user (lossy codec, gaps), also logged
        self._grey_as_colour = False

    # -- what subclasses provide ------------------------------------------------------------
    @abc.abstractmethod
    def _raw(self, start: int) -> Iterator[tuple[int, np.ndarray]]:
        """(index, image) from frame ``start`` on, as the source stores them (2-D, or H x W x C
        in ``colour_order``)."""

    def close(self) -> None:
        """Release the file or decoder; safe to call twice."""
        return None

    def stamps(self) -> Stamps | None:
        """Per-frame timestamps, sequence numbers and laser states, where the source kept them."""
        return None

    # -- the shared part ---------------------------------------------------------------------
    def _settle(self, first: np.ndarray, channels: int, order: str = "bgr") -> None:
        """Fix shape, dtype, bits and colour from the first image; refuse colour without a channel."""
        self.shape = (int(first.shape[0]), int(first.shape[1]))
        self.dtype = first.dtype
        if first.dtype.kind not in "uif":
            raise ReaderError(f"{self.path}: pixels of type {first.dtype} are not grey levels")
        if self.bits is None and first.dtype.kind in "ui":
            self.bits = 8 * first.dtype.itemsize
        if channels not in (1, 3, 4):
            raise ReaderError(f"{self.path}: images of {channels} channels are neither grey nor colour")
        if channels > 1 and self.channel is None and _grey(first):
            self._grey_as_colour = True  # e.g. a grey video decoded to B, G, R: its channels agree
        elif channels > 1:
            self.colour_order = order
            if self.channel is None:
                raise ReaderError(f"{self.path} is colour ({channels} channels): choose one with "
                                  f"--channel {'|'.join(CHANNELS)} (channel= in a camera URI)")

    def note(self, text: str) -> None:
        self.notes.append(text)
        log.info("%s", text)

    def frames(self, start: int = 0, stop: int | None = None) -> Iterator[np.ndarray]:
        """Frames ``start`` .. ``stop``-1 (to the end when None), each a 2-D array."""
        if start < 0:
            raise ReaderError(f"{self.path}: frame {start} does not exist")
        if stop is not None and stop <= start:
            return
        for index, image in self._raw(start):
            yield self._checked(index, image)
            if stop is not None and index + 1 >= stop:
                return

    def _checked(self, index: int, image: np.ndarray) -> np.ndarray:
        if image.ndim == 3 and self._grey_as_colour:
            if not _grey(image):
                raise ReaderError(f"{self.path}: frame {index} is colour after grey ones: choose a channel "
                                  f"with --channel {'|'.join(CHANNELS)} (channel= in a camera URI)")
            image = image[:, :, 0]
        elif image.ndim == 3 and self.colour_order is not None:
            image = select_channel(image, self.channel or "luma", self.colour_order)
        elif image.ndim == 3 and image.shape[2] == 1:
            image = image[:, :, 0]
        if image.ndim != 2:
            raise ReaderError(f"{self.path}: frame {index} has shape {image.shape}, not a 2-D frame")
        if image.shape != self.shape:
            raise ReaderError(f"{self.path}: frame {index} is a {describe_shape(image.shape)} frame after "
                              f"{describe_shape(self.shape)} ones; a recording keeps one frame size")
        if image.dtype != self.dtype:
            raise ReaderError(f"{self.path}: frame {index} is {image.dtype} after {self.dtype} frames")
        return image if image.flags.c_contiguous else np.ascontiguousarray(image)  # what the engine takes

    def window(self, start: int, count: int,
               wrap: Callable[[Iterator[np.ndarray]], Iterator[np.ndarray]] | None = None) -> np.ndarray:
        """Frames ``start`` .. ``start+count-1`` as one (count, H, W) array: the only place a
        reader holds more than a frame, on purpose (a batch map needs its window). ``wrap``
        wraps the frames as they are read (a progress bar)."""
        check_bytes(self.path, f"a window of {count} frames", count * math.prod(self.shape) * self.dtype.itemsize)
        stack = np.empty((count, *self.shape), self.dtype)
        frames = self.frames(start, start + count)
        taken = 0
        for taken, frame in enumerate(wrap(frames) if wrap is not None else frames, start=1):
            stack[taken - 1] = frame
        if taken < count:
            raise ReaderError(f"{self.path}: ends after {start + taken} frames; frames {start}.."
                              f"{start + count - 1} were asked for")
        return stack

    def __iter__(self) -> Iterator[np.ndarray]:
        """Every frame from the first, as :meth:`frames` gives them: ``for frame in open_frames(path)``."""
        return self.frames()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
