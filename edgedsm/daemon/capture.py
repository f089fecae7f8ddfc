"""The capture thread: camera → bounded queue, dropping the oldest frame when the queue is full.

A slow consumer never stalls a camera (it cannot wait: frames would be lost in the driver
instead, uncounted); a source that can wait (a replay as fast as possible) is held back instead.
Reconnection is the camera's own (``Camera.frames(reconnect=...)``): this thread is told when
the device is lost and when it is back, and reports both to the pipeline thread.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import Counter

from edgedsm.config import CameraSection
from edgedsm.daemon.probes import PipelineProbes
from edgedsm.devices.camera.base import Backoff, Camera, ReconnectWatch
from edgedsm.errors import DeviceError
from edgedsm.frames import Frame

log = logging.getLogger(__name__)

#: How long a held-back source waits per try for room in the queue (s); bounds its reaction to stop.
HOLD_BACK_POLL_S = 0.1


class Capture:
    """Owns the capture thread and its queue (see the module docstring)."""

    def __init__(self, camera: Camera, settings: CameraSection, queue_frames: int, counters: Counter[str],
                 probes: PipelineProbes | None = None) -> None:
        self.camera = camera
        self.settings = settings
        self.counters = counters
        self.probes = probes or PipelineProbes()
        self.frames: queue.Queue[Frame] = queue.Queue(maxsize=queue_frames)
        self.lost = threading.Event()  # set while the camera is away
        self.error: BaseException | None = None  # what ended the thread, for the pipeline thread to raise
        self.loss_reason = ""  # the latest loss, in words
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # -- lifecycle (pipeline thread) ----------------------------------------------------------
    def open(self) -> None:
        """Open the camera and apply the configured settings (they are re-applied on reconnect)."""
        self.camera.open()
        cam = self.settings
        if cam.pixel_format:
            self.camera.set_pixel_format(cam.pixel_format)
        if cam.exposure_us:
            self.camera.set_exposure(cam.exposure_us)
        if cam.frame_interval_s:
            self.camera.set_frame_interval(cam.frame_interval_s)

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

    def enqueue(self, frame: Frame) -> None:
        """Queue one frame: held back for a source that can wait, else dropping the oldest."""
        if self.probes.frame_queued is not None:
            self.probes.frame_queued(frame, time.monotonic())
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
