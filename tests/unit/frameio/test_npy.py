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


# -- read, never mapped: a file changing under the reader is an error, not SIGBUS (issue 34) ----

def _ramp(path, count=30, shape=(16, 16), dtype=np.uint8):
    stack = (np.arange(count)[:, None, None] + np.zeros(shape)).astype(dtype)
    np.save(path, stack)
    return stack


def test_frames_are_read_not_mapped(tmp_path):
    stack = _ramp(tmp_path / "s.npy")
    with open_frames(tmp_path / "s.npy") as reader:
        first = next(reader.frames())
        with open("/proc/self/maps") as maps_file:
            maps = maps_file.read()
        assert str(tmp_path / "s.npy") not in maps
        assert first.base is None or first.base.base is None  # its own memory
        assert np.array_equal(np.stack(list(reader.frames())), stack)
        assert np.array_equal(reader.window(7, 5), stack[7:12])


@pytest.mark.parametrize("change", ["truncate", "rewrite_same_size", "replace", "remove"])
def test_a_file_changed_while_read_is_a_reader_error(tmp_path, change):
    import os

    path = tmp_path / "s.npy"
    _ramp(path)
    with open_frames(path) as reader:
        frames = reader.frames()
        assert int(next(frames)[0, 0]) == 0
        if change == "truncate":
            os.truncate(path, path.stat().st_size // 2)
        elif change == "rewrite_same_size":
            data = bytearray(path.read_bytes())
            data[-1] ^= 0xFF
            with open(path, "r+b") as file:
                file.write(bytes(data))
            os.utime(path, ns=(1, 1))  # a different modification time, as any rewrite gives
        elif change == "replace":
            np.save(tmp_path / "other.npy", np.zeros((30, 16, 16), np.uint8))
            os.replace(tmp_path / "other.npy", path)
        else:
            path.unlink()
        with pytest.raises(ReaderError, match=r"s\.npy: frame 1 cannot be read: it (changed|was)") as refused:
            next(frames)
        assert refused.value.exit_code == 65


def test_big_endian_samples_come_in_the_machines_order(tmp_path):
    stack = np.random.default_rng(2).integers(0, 4096, (4, 6, 5)).astype(">u2")
    np.save(tmp_path / "be.npy", stack)
    with open_frames(tmp_path / "be.npy") as reader:
        got = np.stack(list(reader.frames()))
        assert reader.dtype == np.uint16 and got.dtype.isnative
        assert np.array_equal(got, stack.astype(np.uint16)) and np.array_equal(reader.window(1, 2), got[1:3])


def test_version_2_headers_and_trailing_bytes_are_read(tmp_path):
    stack = np.arange(2 * 3 * 4, dtype=np.uint16).reshape(2, 3, 4)
    with open(tmp_path / "v2.npy", "wb") as file:
        np.lib.format.write_array(file, stack, version=(2, 0))
        file.write(b"trailing")
    with open_frames(tmp_path / "v2.npy") as reader:
        assert np.array_equal(np.stack(list(reader.frames())), stack)


def test_a_closed_reader_reads_nothing(tmp_path):
    _ramp(tmp_path / "s.npy")
    reader = open_frames(tmp_path / "s.npy")
    reader.close()
    reader.close()
    with pytest.raises(ReaderError, match="read after close"):
        next(reader.frames())


def test_a_reader_is_iterable_like_its_frames(tmp_path):
    stack = np.arange(5 * 3 * 4, dtype=np.uint16).reshape(5, 3, 4)
    np.save(tmp_path / "s.npy", stack)
    with open_frames(tmp_path / "s.npy") as reader:
        got = [frame.copy() for frame in reader]
    assert len(got) == 5 and all(np.array_equal(a, b) for a, b in zip(got, stack, strict=True))
