"""The noise patches (docs/noise.md, §5c): the square each region is judged by and the ring of
its last frames."""

from __future__ import annotations

import numpy as np
import pytest

from edgedsm.analysis import RegionBox
from edgedsm.noise_patches import MAX_PATCH_FRAMES, NoisePatches, PatchWindow, patch_of


@pytest.mark.parametrize("side", [16, 64])
def test_the_patch_is_centred_in_the_region_and_a_ring_is_judged_on_its_own_pixels(side):
    yy, xx = np.mgrid[:100, :120]
    ring = (np.hypot(yy - 50, xx - 60) < 40) & (np.hypot(yy - 50, xx - 60) > 25)
    box = RegionBox.of(ring)
    rows, cols, mask = patch_of(box, side)
    assert (rows.stop - rows.start, cols.stop - cols.start) == (side, side) == mask.shape
    assert mask.any() and np.array_equal(mask, ring[rows, cols])
    square = np.zeros((100, 120), bool)
    square[10:30, 40:50] = True
    rows, cols, mask = patch_of(RegionBox.of(square), side)
    assert cols == slice(40, 50) and rows.stop - rows.start == min(side, 20) and rows.start >= 10
    assert rows.stop <= 30 and rows.start <= 19 < rows.stop and mask.all()  # holds the centre row


def test_the_patch_rings_give_the_last_frames_in_time_order():
    square = np.zeros((20, 20), bool)
    square[5:15, 5:15] = True
    patches = NoisePatches({"a": RegionBox.of(square)}, frames=4, side=8, dtype=np.dtype(np.uint16), bits=12)
    frames = [np.full((20, 20), k, np.uint16) for k in range(7)]
    for frame in frames[:3]:
        patches.push(frame)
    assert patches.take() == {}
    for frame in frames[3:]:
        patches.push(frame)
    window = patches.take()["a"]
    assert window.frames[:, 0, 0].tolist() == [3, 4, 5, 6] and window.top == 4095.0
    window.frames[:] = 0  # a copy: the ring is untouched
    assert patches.take()["a"].frames[:, 0, 0].tolist() == [3, 4, 5, 6]
    assert NoisePatches({"a": RegionBox.of(square)}, 10_000, 8, np.dtype(np.uint8), 8).frames == MAX_PATCH_FRAMES


def test_the_region_mean_is_the_mean_of_the_regions_samples() -> None:
    rng = np.random.default_rng(3)
    frames = rng.integers(0, 4096, (40, 24, 30), dtype=np.uint16)
    mask = rng.random((24, 30)) < 0.6
    window = PatchWindow(frames, mask, 4095.0)
    assert window.region_mean() == pytest.approx(float(frames[:, mask].mean()), rel=1e-14)
    assert window.region_mean() != pytest.approx(float(frames.mean()), rel=1e-6)  # the mask is applied
