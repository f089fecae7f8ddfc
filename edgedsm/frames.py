"""The unit of data between a camera and the estimators."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import DTypeLike


def sample_dtype(bits: int) -> np.dtype:
    """The array type of frames with ``bits`` significant bits: uint8 up to 8, else uint16 (what
    cameras deliver, the engines' rings hold, and a frame's memory is counted in)."""
    return np.dtype(np.uint8 if bits <= 8 else np.uint16)


@dataclass(frozen=True, slots=True)
class Frame:
    """One monochrome frame as delivered by a camera.

    ``pixels`` is a 2-D uint8 (<= 8 significant bits) or uint16 array, ``seq`` the camera's
    frame counter (gaps mean frames were lost upstream), ``t_ns`` the acquisition time in
    nanoseconds — the camera's own timestamp where it has one, else the host's monotonic
    clock — and ``bits`` the number of significant bits per pixel.
    """

    pixels: np.ndarray
    seq: int
    t_ns: int
    bits: int

    @property
    def shape(self) -> tuple[int, int]:
        return self.pixels.shape  # type: ignore[return-value]

    @property
    def format(self) -> FrameFormat:
        return FrameFormat(self.shape, self.bits, self.pixels.dtype)


@dataclass(frozen=True, slots=True)
class FrameFormat:
    """What a camera's frames are: (rows, columns), significant bits per pixel and the array's
    dtype (uint8 for <= 8 bits, else uint16, unless a recording stores them wider)."""

    shape: tuple[int, int]
    bits: int
    dtype: np.dtype

    @classmethod
    def of(cls, shape: tuple[int, int], bits: int, dtype: DTypeLike | None = None) -> FrameFormat:
        """The format of ``bits``-bit frames of ``shape``, in ``dtype`` (None: the narrowest)."""
        chosen = np.dtype(dtype) if dtype is not None else sample_dtype(bits)
        return cls((int(shape[0]), int(shape[1])), int(bits), chosen)


class FrameSource(Protocol):
    """Anything that yields frames: a camera driver, a replay, a simulation."""

    def frames(self, count: int | None = None) -> Iterator[Frame]: ...
