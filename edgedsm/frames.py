"""The unit of data between a camera and the estimators."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Protocol

import numpy as np


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


class FrameSource(Protocol):
    """Anything that yields frames: a camera driver, a replay, a simulation."""

    def frames(self, count: int | None = None) -> Iterator[Frame]: ...
