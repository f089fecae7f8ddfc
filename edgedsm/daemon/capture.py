"""The capture thread: camera → bounded queue, dropping the oldest frame when the queue is full.

A slow consumer never stalls a camera (it cannot wait: frames would be lost in the driver
instead, uncounted); a source that can wait (a replay as fast as possible) is held back instead.
The queue is sized by time, not by count: it holds ``acquisition.queue_seconds`` of frames at
the rate measured on the camera's frames (re-measured every ``RATE_FRAMES``), and never more
than ``acquisition.queue_max_mib`` of them; ``acquisition.queue_frames`` fixes a count instead.
What it must absorb is the pipeline thread's longest stall (an evaluation costs it one snapshot
of the engine's sums, about one push; the scheduler of a loaded machine adds more).

Reconnection is the camera's own (``Camera.frames(reconnect=...)``): this thread is told when
the device is lost and when it is back, and reports both to the pipeline thread.
"""

from __future__ import annotations

import logging
import math
import queue
import threading
import time
from collections import Counter

from edgedsm.config import AcquisitionSection, CameraSection
from edgedsm.daemon.probes import PipelineProbes
from edgedsm.devices.camera.base import Backoff, Camera, ReconnectWatch
from edgedsm.errors import DeviceError
from edgedsm.frames import Frame, FrameFormat

log = logging.getLogger(__name__)

#: How long a held-back source waits per try for room in the queue (s); bounds its reaction to stop.
HOLD_BACK_POLL_S = 0.1
#: The queue's length is recomputed from the rate of this many frames.
RATE_FRAMES = 32
#: Length of the queue before the rate and the frame size are known (and its least length).
INITIAL_QUEUE_FRAMES = 16
MIN_QUEUE_FRAMES = 2


def queue_capacity(settings: AcquisitionSection, rate: float | None, frame_bytes: int | None) -> int:
    """Frames the queue holds: ``queue_frames`` if set, else ``queue_seconds`` at ``rate``
    frames/s bounded by ``queue_max_mib``; before the rate is known, the memory bound (the
    start, when kernels load, is when a pipeline stalls longest); before the frame size is
    known, ``INITIAL_QUEUE_FRAMES``."""
    if settings.queue_frames is not None:
        return settings.queue_frames
    if not frame_bytes:
        return INITIAL_QUEUE_FRAMES
    by_memory = settings.queue_max_mib * 2**20 // frame_bytes
    by_time = by_memory if not rate else math.ceil(settings.queue_seconds * rate)
    return max(MIN_QUEUE_FRAMES, min(by_time, by_memory))


def apply_camera_settings(camera: Camera, settings: CameraSection) -> dict[str, object]:
    """Apply a config's pixel format, exposure and frame interval to an open camera; returns the
    values the camera took (by name), for whoever wants to record them."""
    taken: dict[str, object] = {}
    if settings.pixel_format:
        taken["pixel_format"] = camera.set_pixel_format(settings.pixel_format)
    if settings.exposure_us:
        taken["exposure_us"] = camera.set_exposure(settings.exposure_us)
    if settings.frame_interval_s:
        taken["frame_interval_s"] = camera.set_frame_interval(settings.frame_interval_s)
    return taken


class Capture:
    """Owns the capture thread and its queue (see the module docstring)."""

    def __init__(self, camera: Camera, settings: CameraSection, sizing: AcquisitionSection, counters: Counter[str],
                 probes: PipelineProbes | None = None) -> None:
        self.camera = camera
        self.settings = settings
        self.sizing = sizing
        self.counters = counters
        self.probes = probes or PipelineProbes()
        self.frames: queue.Queue[Frame] = queue.Queue(maxsize=queue_capacity(sizing, None, None))
        self._arrivals: list[float] = []  # monotonic times of the last RATE_FRAMES frames
        self._rate_known = False
        self.lost = threading.Event()  # set while the camera is away
        self.error: BaseException | None = None  # what ended the thread, for the pipeline thread to raise
        self.loss_reason = ""  # the latest loss, in words
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # -- lifecycle (pipeline thread) ----------------------------------------------------------
    def open(self) -> None:
        """Open the camera and apply the configured settings (they are re-applied on reconnect)."""
        self.camera.open()
        apply_camera_settings(self.camera, self.settings)

    def frame_format(self) -> FrameFormat | None:
        """The open camera's frames (shape, bits, dtype), None where only a frame tells (or the
        camera could not say: the format is a hint, the first frame decides)."""
        try:
            return self.camera.frame_format()
        except DeviceError as exc:
            log.debug("%s: frame format unknown until the first frame: %s", self.camera.description, exc)
            return None

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="edgedsm-capture", daemon=True)
        self._thread.start()

    def request_stop(self) -> None:
        """Tell the thread to end (it does within a grab or a hold-back poll)."""
        self._stop.set()

    def stop(self, timeout_s: float = 1.0) -> None:
        """Stop the thread (bounded wait) and close the camera."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=timeout_s)
        self.camera.close()

    @property
    def stopping(self) -> bool:
        return self._stop.is_set()

    @property
    def ended(self) -> bool:
        """The thread is gone (a finite source ended, or an error) and every frame was taken."""
        return self._thread is not None and not self._thread.is_alive() and self.frames.empty()

    def take(self, timeout_s: float) -> Frame | None:
        try:
            return self.frames.get(timeout=timeout_s)
        except queue.Empty:
            return None

    def drain(self) -> None:
        """Throw away every frame waiting (exposed under conditions no longer wanted)."""
        while True:
            try:
                self.frames.get_nowait()
            except queue.Empty:
                return

    # -- the thread ---------------------------------------------------------------------------
    def _run(self) -> None:
        cam = self.settings
        backoff = Backoff(initial=cam.reconnect_initial_s, maximum=cam.reconnect_max_s)
        watch = ReconnectWatch(on_lost=self._on_lost, on_reconnected=self._on_reconnected, stop=self._stop)
        try:
            for frame in self.camera.frames(timeout_s=cam.grab_timeout_s, reconnect=backoff, watch=watch):
                if self.lost.is_set():
                    self.lost.clear()  # back only once frames come: a camera that reopens but
                    log.warning("camera delivers frames again")  # stays silent is still down
                self.enqueue(frame)
                if self._stop.is_set():
                    return
            # a finite source (replay) ended, or stopped while reconnecting
        except BaseException as exc:  # handed to the pipeline thread, which stops
            self.error = exc
            self.lost.set()

    def _on_lost(self, cause: DeviceError) -> None:
        log.warning("camera lost: %s", cause)
        self.loss_reason = str(cause)
        self.counters["camera_lost"] += 1
        self.lost.set()

    def _on_reconnected(self) -> None:
        self.counters["camera_reconnects"] += 1
        log.warning("camera reconnected")

    @property
    def capacity(self) -> int:
        """Frames the queue holds now."""
        return self.frames.maxsize

    def _resize(self, frame: Frame, now: float) -> None:
        """Every RATE_FRAMES frames: the queue's length from the measured rate and frame size."""
        if self.sizing.queue_frames is not None:
            return  # a fixed length
        arrivals = self._arrivals
        arrivals.append(now)
        if len(arrivals) == 1 and not self._rate_known:  # the first frame: its size is known
            size = queue_capacity(self.sizing, None, frame.pixels.nbytes)
        elif len(arrivals) < RATE_FRAMES:
            return
        else:
            span = arrivals[-1] - arrivals[0]
            rate = (len(arrivals) - 1) / span if span > 0 else None
            arrivals.clear()
            self._rate_known = rate is not None
            size = queue_capacity(self.sizing, rate, frame.pixels.nbytes)
        with self.frames.mutex:  # a longer queue wakes a held-back source at once
            if size != self.frames.maxsize:
                self.frames.maxsize = size
                self.frames.not_full.notify_all()

    def enqueue(self, frame: Frame) -> None:
        """Queue one frame: held back for a source that can wait, else dropping the oldest."""
        now = time.monotonic()
        if self.probes.frame_queued is not None:
            self.probes.frame_queued(frame, now)
        self._resize(frame, now)
        if not self.camera.paced:
            while not self._stop.is_set():
                try:
                    self.frames.put(frame, timeout=HOLD_BACK_POLL_S)
                    return
                except queue.Full:
                    continue
            return
        while True:
            try:
                self.frames.put_nowait(frame)
                return
            except queue.Full:
                try:
                    oldest = self.frames.get_nowait()
                except queue.Empty:
                    continue
                self.counters["dropped_queue"] += 1
                if self.probes.frame_dropped is not None:
                    self.probes.frame_dropped(oldest, "queue")
