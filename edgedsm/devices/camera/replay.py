"""Replay of recorded frames as a camera: anything ``edgedsm.frameio`` reads (an image folder or
pattern, a multi-page TIFF, an edgedsm recording, a video, a .npy stack), streamed frame by frame.

Pacing: ``rate`` frames per second, the recording's own interval where it has one
(``rate="recorded"``: a recording's timestamps, a video's frame rate, or the ``dt`` given), or
``rate=0`` for as fast as possible. ``loop`` starts again at the end; otherwise ``frames()``
simply ends with the recording. An edgedsm recording gives back its frames' own sequence
numbers and timestamps (continued past the end when looping); other sources count from 0 at
``dt`` (the host clock without one). ``channel`` picks red, green, blue or luma of a colour source.

A recording that cannot be used (not readable as frames, frames that change size, a pixel type
other than uint8/uint16, colour without a channel) raises ``DataError`` naming the file (exit 65).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from edgedsm.devices.camera.base import Camera, EndOfStream, pace
from edgedsm.errors import DataError, DeviceError, EdgedsmError
from edgedsm.frameio import FrameReader, InputMissing, Stamps, open_frames
from edgedsm.frames import Frame, FrameFormat

log = logging.getLogger(__name__)


class ReplayCamera(Camera):
    """Frames from a file or folder, paced like a camera."""

    kind = "replay"

    def __init__(self, path: str | Path, rate: float | str = 0.0, dt: float | None = None,
                 loop: bool = False, bits: int | None = None, channel: str | None = None) -> None:
        super().__init__(f"replay of {path}")
        self.path = Path(path)
        if isinstance(rate, str) and rate != "recorded":
            raise DeviceError(f"rate must be frames/s, 0 (as fast as possible) or 'recorded', not {rate!r}")
        if not isinstance(rate, str) and rate < 0:
            raise DeviceError("rate must be >= 0")
        self.rate = rate
        self.dt = dt
        self.loop = loop
        self.channel = channel
        self._bits = bits
        self._reader: FrameReader | None = None
        self._frames: Iterator[np.ndarray] | None = None
        self._stamps: Stamps | None = None
        self._index = 0  # frames taken in the current pass
        self._passes = 0
        self._seq = 0
        self._interval = 0.0
        self._due = 0.0
        self._timestamp_dt: float | None = None

    def _open_reader(self) -> FrameReader:
        """The reader of ``path`` (a hook: a subclass may read the recording otherwise)."""
        return open_frames(self.path, self.channel)

    def _do_open(self) -> None:
        try:
            reader = self._open_reader()
        except InputMissing:
            raise DeviceError(f"{self.path}: no such file or directory") from None
        if reader.dtype not in (np.uint8, np.uint16):
            reader.close()
            raise DataError(f"{self.path}: frames must be uint8 or uint16, not {reader.dtype}")
        self._reader = reader
        try:
            self._pace_from(reader)
        except BaseException:  # the reader holds the file open: release it
            self._do_close()
            raise
        for note in reader.notes:  # a lossy codec, numbers missing in a series
            log.warning("%s", note)
        self._rewind()
        self._passes = 0

    def _pace_from(self, reader: FrameReader) -> None:
        self._stamps = reader.stamps()
        recorded_dt = self.dt if self.dt is not None else reader.dt
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
        if self._reader is not None:
            self._reader.close()
            self._reader = None
        self._frames = None

    def _do_start(self) -> None:
        self._due = 0.0

    @property
    def frame_count(self) -> int | None:
        return self._reader.count if self._reader is not None else None

    @property
    def reader(self) -> FrameReader | None:
        """The open reader (its notes, shape, stamps), None while closed."""
        return self._reader

    def _rewind(self) -> None:
        assert self._reader is not None
        self._frames = self._reader.frames()
        self._index = 0

    def _next_pixels(self) -> np.ndarray | None:
        assert self._frames is not None
        try:
            pixels = next(self._frames)
        except StopIteration:
            return None
        except EdgedsmError as exc:
            raise DataError(str(exc)) from None
        self._index += 1
        return pixels

    def _do_grab(self, timeout_s: float) -> Frame | None:
        pixels = self._next_pixels()
        if pixels is None and self.loop and self._index > 0:
            self._rewind()
            self._passes += 1
            pixels = self._next_pixels()
        if pixels is None:
            raise EndOfStream(f"{self.description}: end of recording after {self._index} frames")
        if self._interval > 0:
            self._due = pace(self._due, self._interval)
        seq, t_ns = self._numbers()
        return Frame(np.ascontiguousarray(pixels), seq, t_ns, self._frame_bits(pixels.dtype))

    def _numbers(self) -> tuple[int, int]:
        """(seq, t_ns) of the frame just taken: the recording's own, else counted at dt."""
        stamps = self._stamps
        if stamps is not None and self._index - 1 < len(stamps.seq):
            index = self._index - 1
            seq_span = int(stamps.seq[-1] - stamps.seq[0]) + 1
            step_ns = round((stamps.interval_s() or 0.0) * 1e9)
            t_span = int(stamps.t_ns[-1] - stamps.t_ns[0]) + step_ns
            return (int(stamps.seq[index]) + self._passes * seq_span,
                    int(stamps.t_ns[index]) + self._passes * t_span)
        seq = self._seq
        self._seq += 1
        t_ns = round(seq * self._timestamp_dt * 1e9) if self._timestamp_dt else time.monotonic_ns()
        return seq, t_ns

    def _do_frame_format(self) -> FrameFormat | None:
        reader = self._reader
        if reader is None:
            return None
        return FrameFormat.of(reader.shape, self._frame_bits(reader.dtype), reader.dtype)

    def _frame_bits(self, dtype: np.dtype) -> int:
        """The frames' significant bits: as told, as the recording says, else its sample size."""
        return self._bits or (self._reader.bits if self._reader is not None else None) or 8 * dtype.itemsize

    def _do_set_frame_interval(self, seconds: float) -> float:
        self._interval = seconds
        return seconds


def first_frame_shape(path: Path, channel: str | None = None) -> tuple[int, int]:
    """(rows, columns) of a recording's frames, reading its headers and first frame only, with
    the checks the replay camera makes when it opens (``check-config`` refuses what ``run``
    would): ``DataError`` (exit 65) naming the file when it cannot be replayed, ``InputMissing``
    (66) when it is not there."""
    with open_frames(path, channel) as reader:
        if reader.dtype not in (np.uint8, np.uint16):
            raise DataError(f"{path}: frames must be uint8 or uint16, not {reader.dtype}")
        return reader.shape
