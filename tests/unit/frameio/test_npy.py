"""`.npy` stacks: memory-mapped (only the frames read are touched), colour in R, G, B order."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from edgedsm.frameio import ReaderError, open_frames


def test_a_large_stack_is_not_materialised(tmp_path):
    count, shape = 200, (128, 128)
    path = tmp_path / "large.npy"
    stack = np.lib.format.open_memmap(path, mode="w+", dtype=np.uint16, shape=(count, *shape))
    stack[:] = np.arange(count, dtype=np.uint16)[:, None, None]
    stack.flush()
    del stack
    tracemalloc.start()
    try:
        with open_frames(path) as reader:
            window = reader.window(150, 8)
            last = [int(f[0, 0]) for f in reader.frames(195)]
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert window[:, 0, 0].tolist() == list(range(150, 158)) and last == [195, 196, 197, 198, 199]
    assert peak < 12 * shape[0] * shape[1] * 2  # the 8-frame window, not 200 frames


def test_colour_stacks_are_rgb(tmp_path):
    rgb = np.random.default_rng(0).integers(0, 256, (3, 5, 6, 3), dtype=np.uint8)
    np.save(tmp_path / "c.npy", rgb)
    with open_frames(tmp_path / "c.npy", "green") as reader:
        assert np.array_equal(np.stack(list(reader.frames())), rgb[..., 1])
    with pytest.raises(ReaderError, match="colour"):
        open_frames(tmp_path / "c.npy")


@pytest.mark.parametrize(("content", "match"), [
    (b"\x93NUMPY garbage", "not a valid .npy"),
    (None, r"expected a \(N, H, W\) stack"),
])
def test_bad_stacks_are_named(tmp_path, content, match):
    path = tmp_path / "bad.npy"
    if content is None:
        np.save(path, np.zeros((4, 4)))
    else:
        path.write_bytes(content)
    with pytest.raises(ReaderError, match=match):
        open_frames(path)


def test_an_unknown_channel_is_refused(tmp_path):
    np.save(tmp_path / "s.npy", np.zeros((2, 3, 3), np.uint8))
    with pytest.raises(ReaderError, match="unknown channel 'purple'"):
        open_frames(tmp_path / "s.npy", "purple")
