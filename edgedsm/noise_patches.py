"""Noise patches: the last frames of a small square at each region's centre, from which the
daemon's evaluator (and ``analyze --timeline``) judge the region's light and its noise floor
(docs/noise.md). The daemon's pipeline thread pushes every frame.

The streaming engine keeps sums, not frames (and in exponential or tumbling mode no window of
frames at all), while the noise floor needs each pixel's window mean and the noise model needs
the frames' temporal structure. A patch of ``estimator.noise_patch``² pixels per region is a few
MB at most, whatever the frame size; copying it costs microseconds per frame. Its pixels stand
for the region's: the floor follows their window means, so a region lit very unevenly is judged
by its centre (docs/noise.md says so).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from edgedsm.analysis import RegionBox
from edgedsm.estimators.noise_summary import full_scale

#: The patch keeps at most this many frames (of a longer window, the latest): the floor's value does
#: not depend on N, only its spread, which a shorter sample over-states (the safe side).
MAX_PATCH_FRAMES = 512


@dataclass(frozen=True)
class PatchWindow:
    """A region's patch over the last frames: a (N, h, w) copy in time order, the region's pixels
    in the patch (boolean (h, w)) and the camera's full scale (DN)."""

    frames: np.ndarray
    mask: np.ndarray
    top: float

    def region_mean(self) -> float:
        """The region's mean over the window (DN): of its pixels' window means, which numpy sums
        straight along time (a copy of the region's pixels first took several times as long)."""
        return float(self.frames.mean(axis=0, dtype=np.float64)[self.mask].mean())


def patch_of(box: RegionBox, side: int) -> tuple[slice, slice, np.ndarray]:
    """The rows, columns and region mask of the square of up to ``side`` pixels centred on the
    region pixel nearest to its bounding box's centre (a ring's centre is not in the ring)."""
    height, width = box.mask.shape
    rows, cols = np.nonzero(box.mask)
    nearest = int(np.argmin((rows - (height - 1) / 2.0) ** 2 + (cols - (width - 1) / 2.0) ** 2))
    ph, pw = min(side, height), min(side, width)
    r0 = int(np.clip(rows[nearest] - ph // 2, 0, height - ph))
    c0 = int(np.clip(cols[nearest] - pw // 2, 0, width - pw))
    mask = np.ascontiguousarray(box.mask[r0:r0 + ph, c0:c0 + pw])
    return (slice(box.rows.start + r0, box.rows.start + r0 + ph),
            slice(box.cols.start + c0, box.cols.start + c0 + pw), mask)


class NoisePatches:
    """Rings of the last ``frames`` patches of each region (pipeline thread only)."""

    def __init__(self, regions: dict[str, RegionBox], frames: int, side: int, dtype: np.dtype,
                 bits: int | None) -> None:
        self.frames = min(frames, MAX_PATCH_FRAMES)
        self.bits = bits
        self._patches = {name: patch_of(box, side) for name, box in regions.items()}
        self._rings = {name: np.zeros((self.frames, rows.stop - rows.start, cols.stop - cols.start), dtype)
                       for name, (rows, cols, _) in self._patches.items()}
        self._next = 0  # ring position of the next frame
        self._count = 0  # frames pushed since the last reset

    def push(self, pixels: np.ndarray) -> None:
        """Copy each region's patch of the frame pushed to the engine (same coordinates)."""
        for name, (rows, cols, _) in self._patches.items():
            self._rings[name][self._next] = pixels[rows, cols]
        self._next = (self._next + 1) % self.frames
        self._count += 1

    def reset(self) -> None:
        self._next = self._count = 0

    @property
    def full(self) -> bool:
        return self._count >= self.frames

    def take(self) -> dict[str, PatchWindow]:
        """Every region's patch window, oldest frame first (copies); empty until the rings are full."""
        if not self.full:
            return {}
        windows = {}
        for name, (_, _, mask) in self._patches.items():
            frames = np.roll(self._rings[name], -self._next, axis=0)
            windows[name] = PatchWindow(frames, mask, full_scale(frames, self.bits))
        return windows
