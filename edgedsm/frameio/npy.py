"""A ``.npy`` stack: (N, H, W) grey frames, or (N, H, W, 3|4) colour in R, G, B order (numpy's
convention), read frame by frame with explicit reads at the header's offset: only the frames
read are in memory, and nothing is memory-mapped.

Never mapped, because a mapped file that is truncated or rewritten while it is read kills the
process with SIGBUS (a replayed recording copied over in place, with the laser on). Every read
checks that the file is still the one opened (same size and modification time; the path still
names it) and that it gave every byte asked for; otherwise ``ReaderError`` (exit 65) says the
file changed while it was read, and the replay camera ends as on any bad data.

The header is checked before anything is allocated: a pickled object dtype, a structured or
sub-array dtype, Fortran order, a shape that is not (N, H, W[, C]), zero or negative
dimensions, a frame beyond the memory budget (``edgedsm.frameio.budget``) and a file shorter
than the frames its header claims are refused, each in one line naming the file. Big-endian
samples are swapped to the machine's order as they are read.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from edgedsm.frameio.base import FrameReader, ReaderError
from edgedsm.frameio.budget import check_bytes, check_count, check_frame

_MAGIC = b"\x93NUMPY"


def read_npy_header(path: Path, file: object) -> tuple[tuple[int, ...], np.dtype, int]:
    """(shape, dtype, offset of the data) from an open ``.npy`` file, every claim checked that
    does not depend on the frame size; ``ReaderError`` for anything else."""
    fmt = np.lib.format
    try:
        if file.read(6) != _MAGIC:  # type: ignore[attr-defined]
            raise ValueError("no .npy magic string")
        file.seek(0)  # type: ignore[attr-defined]
        version = fmt.read_magic(file)
        if version == (1, 0):
            shape, fortran, dtype = fmt.read_array_header_1_0(file, max_header_size=10_000)
        elif version in ((2, 0), (3, 0)):
            shape, fortran, dtype = fmt.read_array_header_2_0(file, max_header_size=10_000)
        else:
            raise ValueError(f"unknown .npy format version {version}")
        offset = file.tell()  # type: ignore[attr-defined]
    except (ValueError, OSError, EOFError, SyntaxError, TypeError, OverflowError) as exc:
        text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ReaderError(f"{path}: not a valid .npy array: {text}") from None
    if dtype.hasobject:
        raise ReaderError(f"{path}: holds Python objects (a pickled array), which are never loaded; "
                          f"save grey levels (uint8, uint16, float)")
    if dtype.names is not None or dtype.subdtype is not None:
        raise ReaderError(f"{path}: holds records of type {dtype} (a structured array), not grey levels")
    if dtype.kind not in "uif":
        raise ReaderError(f"{path}: pixels of type {dtype} are not grey levels")
    if fortran and len(shape) > 1:
        raise ReaderError(f"{path}: is stored in Fortran order, where a frame is not contiguous in the file; "
                          f"save it as np.ascontiguousarray(stack)")
    return tuple(shape), dtype, offset


class NpyReader(FrameReader):
    kind = "npy"

    def __init__(self, path: Path, channel: str | None = None) -> None:
        super().__init__(path, channel)
        self._fd = -1
        try:
            file = open(path, "rb")  # noqa: SIM115 (its descriptor is kept; closed by close())
        except OSError as exc:
            raise ReaderError(f"{path}: cannot be opened: {exc.strerror or exc}") from None
        try:
            self._open(file)
        except BaseException:
            file.close()
            raise
        self._file = file

    def _open(self, file: object) -> None:
        path = self.path
        shape, dtype, offset = read_npy_header(path, file)
        colour = len(shape) == 4 and shape[3] in (3, 4)
        if len(shape) != 3 and not colour:
            raise ReaderError(f"{path}: expected a (N, H, W) stack (or N, H, W, 3 in colour), got shape {shape}")
        check_count(path, shape[0], ".npy header")
        self._frame_bytes = check_frame(path, shape[1:], dtype.itemsize, ".npy header")
        self._fd = file.fileno()  # type: ignore[attr-defined]
        info = os.fstat(self._fd)
        self._identity = (info.st_dev, info.st_ino)
        self._stamp = (info.st_size, info.st_mtime_ns)
        needed = offset + shape[0] * self._frame_bytes
        if info.st_size < needed:
            whole = (info.st_size - offset) // self._frame_bytes if info.st_size > offset else 0
            raise ReaderError(f"{path}: truncated: the header claims {shape[0]} frames of "
                              f"{'x'.join(str(n) for n in shape[1:])} ({needed:,} bytes), the file has "
                              f"{info.st_size:,} bytes ({whole} whole frames)")
        self._offset = offset
        self._frame_shape = tuple(shape[1:])
        self._stored = dtype
        self.count = int(shape[0])
        self._settle(self._read(0, 1)[0], shape[3] if colour else 1, order="rgb")

    def _changed(self) -> str | None:
        """Why the file is no longer the one opened, or None."""
        info = os.fstat(self._fd)
        if (info.st_size, info.st_mtime_ns) != self._stamp:
            return (f"it changed while being read (now {info.st_size:,} bytes, was {self._stamp[0]:,}; "
                    f"truncated or rewritten in place?)")
        try:
            named = os.stat(self.path)
        except OSError:
            return "it was removed or renamed while being read"
        if (named.st_dev, named.st_ino) != self._identity:
            return "it was replaced by another file while being read"
        return None

    def _read(self, start: int, count: int) -> np.ndarray:
        """Frames ``start`` .. ``start+count-1`` as one new (count, H, W[, C]) array in the machine's
        byte order: one explicit read, checked."""
        if self._fd < 0:
            raise ReaderError(f"{self.path}: read after close")
        stack = np.empty((count, *self._frame_shape), self._stored)
        view = memoryview(stack.reshape(-1).view(np.uint8))
        position, done = self._offset + start * self._frame_bytes, 0
        try:
            while done < len(view):
                got = os.preadv(self._fd, [view[done:]], position + done)
                if got <= 0:
                    break
                done += got
        except OSError as exc:
            raise ReaderError(f"{self.path}: frame {start + done // self._frame_bytes} cannot be read: "
                              f"{exc.strerror or exc}") from None
        change = self._changed()
        if done < len(view) or change is not None:
            index = start + done // self._frame_bytes if done < len(view) else start
            raise ReaderError(f"{self.path}: frame {index} cannot be read: {change or 'the file ended early'}")
        if not self._stored.isnative:
            stack = stack.byteswap().view(self._stored.newbyteorder("="))
        return stack

    def _raw(self, start: int) -> Iterator[tuple[int, np.ndarray]]:
        for index in range(start, self.count or 0):
            yield index, self._read(index, 1)[0]

    def window(self, start: int, count: int,
               wrap: Callable[[Iterator[np.ndarray]], Iterator[np.ndarray]] | None = None) -> np.ndarray:
        if len(self._frame_shape) == 2 and start >= 0 and count > 0 and start + count <= (self.count or 0):
            check_bytes(self.path, f"a window of {count} frames", count * self._frame_bytes)
            return self._read(start, count)  # one read of the window, nothing else
        return super().window(start, count, wrap)

    def close(self) -> None:
        if self._fd >= 0:
            self._fd = -1
            self._file.close()
