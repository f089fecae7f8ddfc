"""The daemon's recording files, on a thread of their own: frames from a bounded queue into
edgedsm recordings (:class:`edgedsm.frameio.recording.RecordingWriter`: one BigTIFF page per
frame, unbuffered, readable up to the last complete page after a SIGKILL), named
``<device>-<UTC time>-<label>.tif``, with retention by total size and age (oldest first, only
files whose name this device writes).

Size: before each page, the oldest closed files are deleted until the folder's recordings plus
the page to come (the largest page seen so far) fit in ``max_bytes``, and a file is closed once
it holds a quarter of ``max_bytes``, so the total never exceeds ``max_bytes``. Age: files whose
last write is older than ``keep_days`` go after each file closes and every minute.

A disk that refuses a write (full, read-only, I/O error): the frame is dropped and counted,
``on_fault`` hears the disk's own words once per episode, writing is tried again after a backoff
(1 s doubling to 30 s) in a new file; the first page that goes through ends the episode (logged).
"""

from __future__ import annotations

import logging
import os
import re
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path

from edgedsm.config.recording import RecordingSection
from edgedsm.errors import EdgedsmError
from edgedsm.frameio.recording import OutputExists, RecordingWriter
from edgedsm.frames import Frame
from edgedsm.priority import lower_priority

log = logging.getLogger(__name__)

#: What a file holds, the last part of its name.
FILE_LABELS = ("continuous", "alerts", "timelapse", "clip")
#: A queued frame: (segment id, file label, frame, laser state, monotonic time taken); a frame of
#: ``CLOSE`` ends the segment's file.
QueuedFrame = tuple[int, str, "Frame | None", str, float]
CLOSE = None
_STOP = -1  # the segment id of the item that stops the writer
RETRY_FIRST_S, RETRY_MAX_S = 1.0, 30.0
EXPIRE_EVERY_S = 60.0
FILES_PER_BUDGET = 4  # a file is closed at max_bytes / FILES_PER_BUDGET
#: Niceness of the writer thread (edgedsm.priority), relative to the process: nicer than the
#: evaluator's 5, so that when cores are short the recording waits (its queue, then its drops),
#: not the measurement.
RECORDING_NICE = 10


class FrameQueue:
    """A FIFO of queued frames bounded by their pixels' bytes; ``put`` never waits."""

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = max_bytes
        self._items: deque[QueuedFrame] = deque()
        self._bytes = 0
        self._changed = threading.Condition()

    def put(self, item: QueuedFrame, force: bool = False) -> bool:
        """Append ``item``; False (not queued) when its pixels would pass the bound (one frame
        is always taken into an empty queue; ``force``: markers)."""
        size = item[2].pixels.nbytes if item[2] is not None else 0
        with self._changed:
            if not force and self._items and self._bytes + size > self.max_bytes:
                return False
            self._items.append(item)
            self._bytes += size
            self._changed.notify_all()
        return True

    def get(self, timeout_s: float) -> QueuedFrame | None:
        """The oldest item, or None after ``timeout_s`` without one."""
        with self._changed:
            if not self._items:
                self._changed.wait(timeout_s)
                if not self._items:
                    return None
            item = self._items.popleft()
            self._bytes -= item[2].pixels.nbytes if item[2] is not None else 0
            if not self._items:
                self._changed.notify_all()
            return item

    def wait_empty(self, timeout_s: float) -> bool:
        with self._changed:
            return self._changed.wait_for(lambda: not self._items, timeout_s)

    def __len__(self) -> int:
        return len(self._items)


def utc_stamp(wall_s: float) -> str:
    """``20260102T030405.678Z``: sorts as time does."""
    return time.strftime("%Y%m%dT%H%M%S", time.gmtime(wall_s)) + f".{int(wall_s % 1 * 1000):03d}Z"


def name_pattern(device: str) -> re.Pattern[str]:
    """The names this device's recorder writes (retention touches no other file)."""
    return re.compile(rf"^{re.escape(device)}-\d{{8}}T\d{{6}}\.\d{{3}}Z-({'|'.join(FILE_LABELS)})(-\d+)?\.tif$")


class RecordingFiles:
    """The writer thread and the folder's accounting (see the module docstring). Counters are
    written by the writer thread only and read from any."""

    def __init__(self, directory: Path, device: str, section: RecordingSection, queue: FrameQueue, *,
                 source: str, header: dict[str, object], wall: Callable[[], float],
                 monotonic: Callable[[], float], on_fault: Callable[[str], None]) -> None:
        self.directory = directory
        self.device = device
        self.section = section
        self.queue = queue
        self.source = source
        self.header = header
        self._wall, self._monotonic, self._on_fault = wall, monotonic, on_fault
        self._pattern = name_pattern(device)
        self._closed: deque[tuple[Path, int]] = deque()  # this device's files, oldest first, and their sizes
        self._closed_bytes = 0
        self._current: RecordingWriter | None = None
        self._current_segment = 0
        self.current_bytes = 0
        self._page_bytes = 0  # the largest page written so far (what the next one is taken to need)
        self.written = self.dropped = self.deleted = 0
        self.bytes_written = 0  # since start (retention deletes some of it)
        self.error: str | None = None  # the disk's refusal, while it lasts
        self._retry_at = float("-inf")
        self._backoff = RETRY_FIRST_S
        self._deadline: float | None = None  # stopping: queued frames after this are dropped
        self._busy = False
        self._thread = threading.Thread(target=self._run, name="edgedsm-recording", daemon=True)

    @property
    def count(self) -> int:
        return len(self._closed) + (self._current is not None)

    @property
    def total_bytes(self) -> int:
        return self._closed_bytes + self.current_bytes

    @property
    def file_max(self) -> int:
        return self.section.max_bytes // FILES_PER_BUDGET

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout_s: float) -> None:
        """Write what is queued until ``timeout_s`` has passed, then close the file."""
        self._deadline = self._monotonic() + 0.8 * timeout_s
        self.queue.put((_STOP, "", CLOSE, "none", 0.0), force=True)
        if self._thread.is_alive():
            self._thread.join(timeout_s)

    def wait_idle(self, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while self._busy and time.monotonic() < deadline:
            time.sleep(0.01)
        return not self._busy

    # -- the writer thread ---------------------------------------------------------------------
    def _run(self) -> None:
        lower_priority(RECORDING_NICE)
        self._scan()
        next_expiry = self._monotonic() + EXPIRE_EVERY_S
        while True:
            item = self.queue.get(0.5)
            if self._monotonic() >= next_expiry:
                next_expiry = self._monotonic() + EXPIRE_EVERY_S
                self._expire()
            if item is None:
                continue
            if item[0] == _STOP:
                break
            self._busy = True
            try:
                self._handle(item)
            except Exception:  # the recorder must never end silently: log, drop, go on
                log.exception("recording: frame not written")
                self.dropped += 1
            finally:
                self._busy = False
        self._close_current()

    def _scan(self) -> None:
        """This device's files already in the folder (earlier runs, a killed one's included)."""
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            names = sorted(entry.name for entry in os.scandir(self.directory) if self._pattern.match(entry.name))
        except OSError as exc:
            self._failed(f"{self.directory}: {exc.strerror or exc}")
            return
        for name in names:
            path = self.directory / name
            try:
                size = path.stat().st_size
            except OSError:
                continue
            self._closed.append((path, size))
            self._closed_bytes += size
        self._expire()
        self._make_room(0)

    def _handle(self, item: QueuedFrame) -> None:
        segment, label, frame, laser, taken = item
        if frame is None:
            if self._current is not None and self._current_segment == segment:
                self._close_current()
            return
        now = self._monotonic()
        if self._deadline is not None and now > self._deadline:
            self.dropped += 1
            return
        if self.error is not None and now < self._retry_at:
            self.dropped += 1
            return
        need = self._page_bytes or frame.pixels.nbytes + 4096
        try:
            if self._current is None or self._current_segment != segment or \
                    (self._current.count and self.current_bytes + need > self.file_max):
                self._close_current()
                self._open(segment, label, taken)
            self._make_room(need)
            writer = self._current
            assert writer is not None
            writer.write(frame, laser)
            size = writer.path.stat().st_size
        except (EdgedsmError, OSError) as exc:
            self.dropped += 1
            self._failed(str(exc) if isinstance(exc, EdgedsmError) else f"{self.directory}: {exc.strerror or exc}")
            return
        self._page_bytes = max(self._page_bytes, size - self.current_bytes)
        self.bytes_written += size - self.current_bytes
        self.current_bytes = size
        self.written += 1
        if self.error is not None:
            log.warning("recording: %s takes writes again (%d frames dropped so far)", self.directory, self.dropped)
            self.error, self._backoff = None, RETRY_FIRST_S

    def _open(self, segment: int, label: str, taken: float) -> None:
        wall = self._wall() - (self._monotonic() - taken)
        stem = f"{self.device}-{utc_stamp(wall)}-{label}"
        self.directory.mkdir(parents=True, exist_ok=True)
        for attempt in range(100):
            path = self.directory / (f"{stem}.tif" if attempt == 0 else f"{stem}-{attempt}.tif")
            try:
                self._current = RecordingWriter(path, codec=self.section.codec, source=self.source, header=self.header)
                break
            except OutputExists:
                continue
        else:
            raise EdgedsmError(f"{self.directory}: no free name for {stem}")
        self._current_segment = segment
        self.current_bytes = 0
        log.info("recording to %s", self._current.path)

    def _close_current(self) -> None:
        writer, self._current = self._current, None
        if writer is None:
            return
        try:
            writer.close()
        except EdgedsmError as exc:
            log.warning("recording: %s", exc)
        try:
            size = writer.path.stat().st_size  # a file with no frame was removed by close()
        except OSError:
            size = None
        if size is not None:
            self._closed.append((writer.path, size))
            self._closed_bytes += size
            log.info("recorded %s: %d frames, %.1f MB", writer.path.name, writer.count, size / 1e6)
        self.current_bytes = 0
        self._expire()

    def _failed(self, reason: str) -> None:
        """The disk refused: the file so far is kept, writing is tried again after a backoff."""
        self._close_current()
        self._retry_at = self._monotonic() + self._backoff
        self._backoff = min(2 * self._backoff, RETRY_MAX_S)
        if self.error is None:
            self.error = reason
            log.error("recording: %s; frames are dropped (and counted) until it takes writes again; "
                      "measuring goes on", reason)
            self._on_fault(reason)

    # -- retention -----------------------------------------------------------------------------
    def _make_room(self, need: int) -> None:
        """Delete the oldest closed files until everything plus ``need`` bytes fits ``max_bytes``."""
        budget = self.section.max_bytes
        while self._closed and self._closed_bytes + self.current_bytes + need > budget:
            self._delete(self._closed.popleft(), "over max_bytes")

    def _expire(self) -> None:
        """Delete closed files last written more than ``keep_days`` ago."""
        cutoff = self._wall() - self.section.keep_days * 86_400
        kept: deque[tuple[Path, int]] = deque()
        for entry in self._closed:
            try:
                old = entry[0].stat().st_mtime < cutoff
            except FileNotFoundError:
                self._closed_bytes -= entry[1]
                continue
            except OSError:
                old = False
            if old:
                self._delete(entry, f"older than {self.section.keep_days:g} days")
            else:
                kept.append(entry)
        self._closed = kept

    def _delete(self, entry: tuple[Path, int], why: str) -> None:
        path, size = entry
        self._closed_bytes -= size
        try:
            path.unlink()
        except FileNotFoundError:
            return
        except OSError as exc:
            log.error("recording: %s could not be deleted (%s): %s", path, why, exc.strerror or exc)
            return
        self.deleted += 1
        log.info("recording: deleted %s (%s)", path.name, why)
