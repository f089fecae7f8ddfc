"""Decoding the next frame while the caller works on this one: :class:`Prefetched` wraps a frame
iterator (a reader's ``frames()``) and runs it on one background thread, ``depth`` frames ahead.

Decoders (OpenCV's ``imread``, tifffile's codecs, PyAV) and the streaming engine's compiled
kernels release the GIL, so on a machine with a core to spare the decoding of frame t+1 overlaps
the pushes of frame t: ``analyze --timeline`` then takes about the longer of the two instead of
their sum (docs/recording.md, "The paper's series size"). Memory: ``depth`` + 1 more frames (those
queued and the one the thread holds until there is room).

The frames come out in order and unchanged (the thread hands over each array the iterator
yielded; the iterator never sees the caller). An exception of the iterator (a ``ReaderError``
naming a damaged file) is raised in the caller at the frame where it happened; closing the
wrapper (``with``, or :meth:`close`) stops the thread and closes the iterator on it before the
reader behind it is closed.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Iterator
from types import TracebackType
from typing import Self

import numpy as np

#: How long the thread waits at a time to hand a frame over before it looks whether it was told
#: to stop (seconds).
POLL_S = 0.1
_END = object()


class Prefetched:
    """``frames`` read ``depth`` (>= 1) frames ahead on a background thread; iterate once."""

    def __init__(self, frames: Iterator[np.ndarray], depth: int = 1, name: str = "edgedsm-decode") -> None:
        if depth < 1:
            raise ValueError(f"depth must be >= 1, got {depth}")
        self._frames = frames
        self._queue: queue.Queue[object] = queue.Queue(maxsize=depth)
        self._stop = threading.Event()
        self._done = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _put(self, item: object) -> bool:
        """Hand ``item`` over; False when told to stop first."""
        while not self._stop.is_set():
            try:
                self._queue.put(item, timeout=POLL_S)
                return True
            except queue.Full:
                continue
        return False

    def _run(self) -> None:
        try:
            for frame in self._frames:
                if not self._put(frame):
                    return
            self._put(_END)
        except BaseException as exc:  # handed to the caller, raised there
            self._put(exc)
        finally:
            close = getattr(self._frames, "close", None)
            if close is not None:
                close()  # a generator's finally clauses run on the thread that ran it

    def __iter__(self) -> Iterator[np.ndarray]:
        return self

    def __next__(self) -> np.ndarray:
        if self._done:
            raise StopIteration
        item = self._queue.get()
        if item is _END:
            self._finish()
            raise StopIteration
        if isinstance(item, BaseException):
            self._finish()
            raise item
        return item  # type: ignore[return-value]

    def _finish(self) -> None:
        self._done = True
        self._thread.join()

    def close(self) -> None:
        """Stop reading ahead and wait for the thread (safe to call twice)."""
        self._done = True
        self._stop.set()
        self._thread.join()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
