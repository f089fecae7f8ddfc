"""Acquisition: the laser relay, dark frames and bursts — whether frames are wanted now.

Runs on the pipeline thread only. The laser is switched on only while frames are wanted, and
off during dark frames, between bursts, at stop and on any error.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable

import numpy as np

from edgedsm.config import AcquisitionSection
from edgedsm.daemon.capture import Capture
from edgedsm.devices.laser.base import LaserRelay
from edgedsm.errors import DeviceError
from edgedsm.frames import Frame
from edgedsm.messages import LaserState

log = logging.getLogger(__name__)


class Acquisition:
    """The laser and the acquisition plan (continuous or bursts, dark frames)."""

    def __init__(self, settings: AcquisitionSection, relay: LaserRelay | None, counters: Counter[str],
                 clock: Callable[[], float], *, burst_started: Callable[[], None],
                 burst_ended: Callable[[float], None]) -> None:
        self.settings = settings
        self.relay = relay
        self.counters = counters
        self.clock = clock
        self._burst_started_hook = burst_started  # a new burst: the estimator starts over
        self._burst_ended_hook = burst_ended      # a burst's end: its final evaluation
        self.laser_on = False
        self.manual_laser: bool | None = None  # set by the `laser` command; None = automatic
        self.dark: np.ndarray | None = None
        self.ambient_level: float | None = None
        self.last_dark_t = -np.inf
        self.burst_started = -np.inf  # bursts mode: when the current burst began
        self.burst_frames = 0

    @property
    def laser(self) -> LaserState:
        return "on" if self.laser_on else "off"

    # -- laser ----------------------------------------------------------------------------------
    def set_laser(self, on: bool, why: str) -> None:
        """Switch the relay (a manual `laser off` wins); raises ``DeviceError`` when it fails."""
        if self.manual_laser is not None:
            on = on and self.manual_laser
        if self.relay is None:
            self.laser_on = on
            return
        if on == self.laser_on and on:
            return
        try:
            (self.relay.on if on else self.relay.off)()
            self.laser_on = on
            log.info("laser %s (%s)", "on" if on else "off", why)
        except DeviceError as exc:
            self.counters["laser_errors"] += 1
            self.laser_on = False
            raise DeviceError(f"laser relay failed while switching {'on' if on else 'off'} ({why}): {exc}") from exc

    def laser_off_quietly(self, why: str) -> None:
        try:
            self.set_laser(False, why)
        except DeviceError as exc:
            log.error("could not switch the laser off (%s): %s", why, exc)

    # -- the plan -------------------------------------------------------------------------------
    def measuring(self, now: float, capture: Capture) -> bool:
        """Whether frames are wanted now; in bursts mode this starts and ends bursts."""
        acq = self.settings
        if acq.mode == "continuous":
            return True
        if self.burst_started > -np.inf and self.burst_frames < acq.burst_frames:
            return True
        if now - self.burst_started >= acq.burst_period_s:
            self.burst_started, self.burst_frames = now, 0
            self._burst_started_hook()
            self.set_laser(True, "burst")
            capture.drain()
            return True
        if self.laser_on:
            self._burst_ended_hook(now)
            self.set_laser(False, "between bursts")
        return False

    def dark_due(self, now: float) -> bool:
        every = self.settings.dark_every_min
        return every > 0 and now - self.last_dark_t >= every * 60

    def take_dark_frames(self, capture: Capture, take: Callable[[float], Frame | None], grab_timeout_s: float) -> None:
        """Laser off, average ``dark_frames`` frames into the dark level (the first is skipped)."""
        count = self.settings.dark_frames
        if count == 0 or self.relay is None:
            return
        self.set_laser(False, "dark frames")
        capture.drain()
        frames = []
        deadline = self.clock() + grab_timeout_s * (count + 2)
        while len(frames) < count + 1 and self.clock() < deadline and not capture.lost.is_set():
            frame = take(0.5)
            if frame is not None:
                frames.append(frame.pixels)
        # the first frame may have been exposed while the relay was still switching
        if len(frames) > 1:
            stack = np.stack(frames[1:]).astype(np.float64)
            self.dark = np.rint(stack.mean(axis=0)).astype(frames[0].dtype)
            self.ambient_level = float(stack.mean())
            log.info("ambient level %.2f grey from %d dark frames", self.ambient_level, len(frames) - 1)
        self.last_dark_t = self.clock()
        capture.drain()
