"""A ``.npy`` stack, memory-mapped: (N, H, W) grey frames, or (N, H, W, 3|4) colour in R, G, B
order (numpy's convention). Only the frames read are paged in."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from edgedsm.frameio.base import FrameReader, ReaderError


class NpyReader(FrameReader):
    kind = "npy"

    def __init__(self, path: Path, channel: str | None = None) -> None:
        super().__init__(path, channel)
        try:
            stack = np.load(path, mmap_mode="r", allow_pickle=False)
        except (ValueError, OSError, EOFError) as exc:
            raise ReaderError(f"{path}: not a valid .npy array: {exc}") from None
        colour = stack.ndim == 4 and stack.shape[3] in (3, 4)
        if stack.ndim != 3 and not colour:
            raise ReaderError(f"{path}: expected a (N, H, W) stack (or N, H, W, 3 in colour), got shape {stack.shape}")
        if stack.shape[0] == 0:
            raise ReaderError(f"{path}: holds no frames")
        self._stack = stack
        self.count = int(stack.shape[0])
        self._settle(stack[0], stack.shape[3] if colour else 1, order="rgb")

    def _raw(self, start: int) -> Iterator[tuple[int, np.ndarray]]:
        for index in range(start, self.count or 0):
            yield index, np.asarray(self._stack[index])

    def window(self, start: int, count: int,
               wrap: Callable[[Iterator[np.ndarray]], Iterator[np.ndarray]] | None = None) -> np.ndarray:
        if self._stack.ndim == 3 and start + count <= (self.count or 0):
            return np.array(self._stack[start:start + count])  # one copy of the window, nothing else
        return super().window(start, count, wrap)

    def close(self) -> None:
        # the map is unmapped when the last frame handed out (a view into it) is gone, not here
        self._stack = np.empty((0, 0, 0), self.dtype)
