"""``[recording]`` in the daemon: which frames go to disk, decided on the pipeline thread at O(1)
per frame, written by :mod:`edgedsm.daemon.recording_files` on a thread of its own.

The :class:`Recorder` is two things:

- the pipeline's frame consumer: :meth:`Recorder.offer` (pipeline thread, every frame taken)
  never blocks and never waits on the disk: it appends a reference to the frame to a bounded
  queue (drivers hand out fresh arrays, never reused) or, in ``alerts`` mode, to an in-memory
  ring bounded by ``pre_s`` and ``ring_max_mib``; a full queue drops the frame and counts it;
- a sink (``edgedsm.daemon.sinks.SINKS``): a ``transition`` or ``fault`` alert starts an
  ``alerts``-mode clip (the ring's ``pre_s`` before it, ``post_s`` after; a later alert extends
  the clip in the same file). ``cmd/record`` starts a clip in any mode (:meth:`request_clip`).

Files: one segment id per file; the pipeline thread starts a new one at each clip and every
``segment_s`` of a continuous or time-lapse recording, so that retention deletes whole files.
A disk that refuses writes is reported once as a ``fault`` alert (``recording: ...``), which
the pipeline publishes (:meth:`pending_faults`) while the measurement goes on.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path

from edgedsm.config.recording import RecordingSection
from edgedsm.daemon.recording_files import CLOSE, FILE_LABELS, FrameQueue, QueuedFrame, RecordingFiles
from edgedsm.frames import Frame
from edgedsm.messages import Alert, AlertKind, RecordingStats

log = logging.getLogger(__name__)

#: Alerts that start an alerts-mode clip; a recording fault of our own does not (its reason
#: starts with ``FAULT_PREFIX``).
CLIP_ALERTS = frozenset({AlertKind.TRANSITION, AlertKind.FAULT})
FAULT_PREFIX = "recording: "


class Recorder:
    """Frames to disk as ``[recording]`` says (see the module docstring)."""

    def __init__(self, section: RecordingSection, directory: Path, device: str, *, source: str = "",
                 header: dict[str, object] | None = None, monotonic: Callable[[], float] = time.monotonic,
                 wall: Callable[[], float] = time.time, start: bool = True) -> None:
        self.section = section
        self.mode = section.mode
        self._monotonic = monotonic
        mib = 2**20
        self.queue = FrameQueue(section.queue_max_mib * mib)
        self.files = RecordingFiles(directory, device, section, self.queue, source=source,
                                    header={"mode": section.mode, **(header or {})}, wall=wall,
                                    monotonic=monotonic, on_fault=self._fault)
        self._ring: deque[QueuedFrame] = deque()
        self._ring_bytes = 0
        self._ring_max = section.ring_max_mib * mib
        self._requests: deque[tuple[str, float]] = deque()  # clips asked for from any thread
        self._faults: deque[str] = deque()  # fault reasons for the pipeline to publish
        self._segment = 0
        self._segment_t: float | None = None  # when the current continuous/time-lapse file began
        self._due = float("-inf")  # time-lapse: when the next frame is kept
        self._clip_end: float | None = None  # monotonic end of the clip being recorded
        self._clip_label = "clip"
        self._closed = False
        self.dropped = 0  # frames the queue refused (the writer counts its own)
        if start:
            self.files.start()

    # -- pipeline thread ----------------------------------------------------------------------
    def offer(self, frame: Frame, laser: str) -> None:
        """One frame the pipeline took, with the laser's state ("on", "off", "unknown", "none")."""
        if self._closed:
            return
        now = self._monotonic()
        if self._requests:
            self._start_clips(now)
        if self._clip_end is not None:
            if now < self._clip_end:
                self._enqueue((self._segment, self._clip_label, frame, laser, now))
                return
            self._end_clip()
        mode = self.mode
        if mode == "alerts":
            self._keep_in_ring((self._segment, "alerts", frame, laser, now))
            return
        if mode == "timelapse":
            if now < self._due:
                return
            every = self.section.every_s
            self._due = self._due + every if now - self._due < every else now + every
        if self._segment_t is None or now - self._segment_t >= self.section.segment_s:
            self._new_segment(now)
        self._enqueue((self._segment, mode, frame, laser, now))

    def pending_faults(self) -> list[str]:
        """Fault reasons to publish as alerts since the last call (pipeline thread)."""
        if not self._faults:
            return []
        faults = []
        while self._faults:
            faults.append(self._faults.popleft())
        return faults

    def _enqueue(self, item: QueuedFrame) -> None:
        if not self.queue.put(item):
            self.dropped += 1

    def _keep_in_ring(self, item: QueuedFrame) -> None:
        ring = self._ring
        ring.append(item)
        self._ring_bytes += item[2].pixels.nbytes  # type: ignore[union-attr]
        oldest = item[4] - self.section.pre_s
        while ring and (ring[0][4] < oldest or self._ring_bytes > self._ring_max):
            self._ring_bytes -= ring.popleft()[2].pixels.nbytes  # type: ignore[union-attr]

    def _new_segment(self, now: float | None) -> None:
        self._segment += 1
        self._segment_t = now

    def _start_clips(self, now: float) -> None:
        while self._requests:
            label, seconds = self._requests.popleft()
            if self._clip_end is not None:  # one clip running: extended, same file
                self._clip_end = max(self._clip_end, now + seconds)
                continue
            self._new_segment(None)
            self._clip_end, self._clip_label = now + seconds, label
            log.info("recording a clip (%s) of %.1f s%s", label, seconds,
                     f" after {len(self._ring)} frames from the ring" if self._ring else "")
            ring, self._ring, self._ring_bytes = self._ring, deque(), 0
            for segment_frame in ring:  # the pre_s before, into the clip's file
                self._enqueue((self._segment, label, *segment_frame[2:]))  # type: ignore[arg-type]

    def _end_clip(self) -> None:
        self._clip_end = None
        self.queue.put((self._segment, self._clip_label, CLOSE, "none", 0.0), force=True)
        self._new_segment(None)  # continuous and time-lapse resume in a file of their own

    # -- any thread ---------------------------------------------------------------------------
    def request_clip(self, seconds: float | None = None, label: str = "clip") -> float:
        """Record every frame for ``seconds`` (default ``post_s``) from the next one, in a file
        of its own (in alerts mode after the ring's ``pre_s``); returns the seconds."""
        if label not in FILE_LABELS:
            raise ValueError(f"label must be one of {FILE_LABELS}")
        seconds = self.section.post_s if seconds is None else seconds
        self._requests.append((label, seconds))
        return seconds

    def stats(self) -> RecordingStats:
        files = self.files
        return RecordingStats(mode=self.mode, dir=str(files.directory), files=files.count, bytes=files.total_bytes,
                              frames_written=files.written, frames_dropped=self.dropped + files.dropped,
                              queued=len(self.queue), clip_active=self._clip_end is not None,
                              files_deleted=files.deleted, error=files.error)

    def _fault(self, reason: str) -> None:
        self._faults.append(FAULT_PREFIX + reason)

    # -- the sink (evaluator thread) ----------------------------------------------------------
    def publish_alert(self, alert: Alert) -> None:
        if self.mode == "alerts" and alert.kind in CLIP_ALERTS and not alert.reason.startswith(FAULT_PREFIX):
            self.request_clip(self.section.post_s, "alerts")

    def publish_state(self, report: object) -> None:
        pass

    def publish_stats(self, stats: object) -> None:
        pass

    def publish_map(self, frame: object) -> None:
        pass

    def flush(self, timeout_s: float) -> bool:
        """Wait (bounded) until the frames handed over are on disk."""
        return self.queue.wait_empty(timeout_s) and self.files.wait_idle(timeout_s)

    def close(self, timeout_s: float) -> None:
        """Stop taking frames; write what is queued within ``timeout_s`` (the rest is dropped
        and counted), close the file."""
        self._closed = True
        self.files.stop(timeout_s)


def make_recorder(section: RecordingSection, directory: Path, device: str, source: str,
                  config_path: str) -> Recorder:
    """The daemon's recorder (``edgedsm.daemon.sinks``)."""
    return Recorder(section, directory, device, source=source, header={"device": device, "config": config_path})

