"""Acquisition: the laser relay, dark frames and bursts — whether a frame is measured now.

Runs on the pipeline thread only. The laser has three states: ``on``, ``off`` and ``unknown``
(after any relay error: never guessed). A frame is measured only while the laser is known on
and the plan wants frames (not during dark frames, between bursts, after a manual `laser off`,
while the camera is down), so no unlit frame reaches the estimator.

After a relay error the laser is unknown: measuring stops, a fault is reported once, and
switching off is retried with backoff until the board confirms it; then the laser goes on again
when frames are wanted. Switching on is rate-limited (``min_switch_interval_s`` between two
switchings on, so at most two switchings per interval); switching off never waits.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable, Iterator

import numpy as np

from edgedsm.config import AcquisitionSection
from edgedsm.devices.camera.base import Backoff
from edgedsm.devices.laser.base import LaserRelay
from edgedsm.errors import DeviceError
from edgedsm.frames import Frame
from edgedsm.messages import LaserState
from edgedsm.publish.commands import CommandResult

log = logging.getLogger(__name__)

#: Least time between two switchings on of the relay (s): a flood of commands or a flapping
#: camera must not wear the relay out or strobe the laser. Switching off never waits.
MIN_SWITCH_INTERVAL_S = 0.5
#: With readback, how often the relay's real state is checked while it should be on (s): a
#: board that went silent or was switched by hand is noticed within this.
RELAY_CHECK_S = 5.0
#: Retrying a switch-off that failed: first delay and cap (s).
OFF_RETRY = Backoff(initial=0.5, factor=2.0, maximum=30.0)


class Acquisition:
    """The laser and the acquisition plan (continuous or bursts, dark frames)."""

    def __init__(self, settings: AcquisitionSection, relay: LaserRelay | None, counters: Counter[str],
                 clock: Callable[[], float], *, on_fault: Callable[[str], None], relit: Callable[[], None],
                 burst_ended: Callable[[float], None], drain: Callable[[], None], camera_lost: Callable[[], bool],
                 min_switch_interval_s: float = MIN_SWITCH_INTERVAL_S) -> None:
        self.settings = settings
        self.relay = relay
        self.counters = counters
        self.clock = clock
        self.min_switch_interval_s = min_switch_interval_s
        self._on_fault = on_fault          # a relay fault (reported once per fault)
        self._relit = relit                # the laser went on: the estimator starts over
        self._burst_ended = burst_ended    # a burst's end: its final evaluation
        self._drain = drain                # throw away the frames queued so far (exposed in another state)
        self._camera_lost = camera_lost    # the camera is down: no dark frame will come
        self.laser: LaserState = "off"
        self.fault_reason = ""  # the last relay error
        self.manual_off = False  # the `laser off` command holds it off until `on` or `auto`
        self.dark: np.ndarray | None = None
        self.ambient_level: float | None = None
        self.last_dark_t = -np.inf
        self.dark_requested = False
        self.burst_started = -np.inf  # bursts mode: when the current burst began
        self.burst_frames = 0
        self._wanted = False
        self._skip = 0  # frames to leave out after switching on (exposed while it switched)
        self._last_on_t = -np.inf
        self._last_check_t = -np.inf
        self._off_delays: Iterator[float] = OFF_RETRY.delays()
        self._next_off_t = -np.inf

    # -- the relay ------------------------------------------------------------------------------
    def _switch(self, on: bool, why: str) -> bool:
        """One switching; a failure makes the laser unknown (reported) and returns False."""
        now = self.clock()
        if self.relay is not None:
            try:
                (self.relay.on if on else self.relay.off)()
            except DeviceError as exc:
                self.counters["laser_errors"] += 1
                self._unknown(f"laser relay failed while switching {'on' if on else 'off'} ({why}): {exc}")
                return False
        self._last_check_t = now
        if self.laser == "unknown":
            log.warning("laser confirmed off after the relay error (%s)", why)
        else:
            log.info("laser %s (%s)", "on" if on else "off", why)
        self.laser = "on" if on else "off"
        if on:
            self._last_on_t = now
            self._skip = 1 if self.relay is not None else 0
            self._relit()
        return True

    def _unknown(self, reason: str) -> None:
        self.fault_reason = reason
        if self.laser != "unknown":
            log.error("%s; the laser state is unknown: measuring stops, switching off is retried", reason)
            self.laser = "unknown"
            self._on_fault(reason)
            self._off_delays = OFF_RETRY.delays()
        delay = next(self._off_delays)
        self._next_off_t = self.clock() + delay
        log.warning("switching the laser off is retried in %.1f s", delay)

    def switch_off(self, why: str) -> bool:
        """Switch off now (never rate-limited); False if it could not be confirmed."""
        return self._switch(False, why)

    def _check_relay(self, now: float) -> None:
        """With readback, ask the board now and then whether the laser really is on."""
        relay = self.relay
        if relay is None or not relay.readback or now - self._last_check_t < RELAY_CHECK_S:
            return
        self._last_check_t = now
        try:
            status = relay.state()
        except DeviceError as exc:
            self.counters["laser_errors"] += 1
            self._unknown(f"laser relay did not report its state: {exc}")
            return
        if status.on is not True:
            self._unknown(f"laser relay reports {status.describe()} while it should be on")

    # -- commands -------------------------------------------------------------------------------
    def refusal(self, now: float) -> str | None:
        """Why a switch-on must wait now (None: it may happen)."""
        since = now - self._last_on_t
        if since < self.min_switch_interval_s:
            return (f"rate limited: at most one switch every {self.min_switch_interval_s:g} s and the laser "
                    f"went on {since:.2f} s ago; try again in {self.min_switch_interval_s - since:.2f} s")
        return None

    def command(self, state: str, now: float, camera_ok: bool) -> CommandResult:
        """The `laser` command: ``off`` holds it off, ``on``/``auto`` give it back to the plan."""
        if state == "off":
            self.manual_off = True
            if self.laser == "off":
                return CommandResult(laser="off")
            if self.laser == "unknown" and now < self._next_off_t:
                return CommandResult.refused(f"{self._fault_text}; next try in {self._next_off_t - now:.1f} s",
                                             self.laser)
            if not self.switch_off("command laser off"):
                return CommandResult.refused(self._fault_text, self.laser)
            return CommandResult(laser=self.laser)
        if self.laser == "unknown":
            return CommandResult.refused(self._fault_text, self.laser)
        if self.laser == "off" and (why := self.refusal(now)):
            return CommandResult.refused(why, self.laser)
        self.manual_off = False
        self.tick(now, camera_ok)
        return CommandResult(laser=self.laser)

    @property
    def _fault_text(self) -> str:
        return f"{self.fault_reason}; the laser state is unknown and switching off is being retried"

    # -- the plan -------------------------------------------------------------------------------
    def _plan_wants(self, now: float) -> bool:
        """Whether the plan wants frames now; in bursts mode this starts and ends bursts."""
        acq = self.settings
        if acq.mode == "continuous":
            return True
        if self.burst_started > -np.inf and self.burst_frames < acq.burst_frames:
            return True
        if now - self.burst_started >= acq.burst_period_s:
            self.burst_started, self.burst_frames = now, 0
            return True
        if self.laser == "on" and self._wanted:
            self._burst_ended(now)  # the burst's final maps and states, once
        return False

    def tick(self, now: float, camera_ok: bool) -> None:
        """Once per loop: retry a pending switch-off; switch the laser as the plan wants."""
        if self.laser == "unknown":
            self._wanted = False
            if now >= self._next_off_t:
                self.switch_off("retry after a relay error")
            return
        wants = self._plan_wants(now) and camera_ok and not self.manual_off
        self._wanted = wants
        if self.laser == "on":
            if not wants:
                why = "manual off" if self.manual_off else "camera down" if not camera_ok else "between bursts"
                self.switch_off(why)
            else:
                self._check_relay(now)
        elif wants and self.refusal(now) is None and self._switch(True, "measuring") and self.relay is not None:
            self._drain()  # frames exposed before the laser was on

    def admit(self) -> bool:
        """Whether the frame just taken is measured: laser known on and frames wanted."""
        if self.laser != "on" or not self._wanted:
            return False
        if self._skip:
            self._skip -= 1
            return False
        self.burst_frames += 1
        return True

    # -- dark frames ----------------------------------------------------------------------------
    def dark_due(self, now: float) -> bool:
        every = self.settings.dark_every_min
        return self.dark_requested or (every > 0 and now - self.last_dark_t >= every * 60)

    def dark_refusal(self) -> str | None:
        """Why the `dark` command cannot be carried out (None: it can)."""
        if self.relay is None:
            return "no laser relay is configured: dark frames need the laser switched off"
        if self.settings.dark_frames == 0:
            return "acquisition.dark_frames is 0"
        return None

    def take_dark_frames(self, take: Callable[[float], Frame | None], grab_timeout_s: float) -> None:
        """Laser off, average ``dark_frames`` frames into the dark level (the first is skipped)."""
        self.dark_requested = False
        count = self.settings.dark_frames
        if count == 0 or self.relay is None or not self.switch_off("dark frames"):
            return
        self._wanted = False
        self._drain()
        frames = []
        deadline = self.clock() + grab_timeout_s * (count + 2)
        while len(frames) < count + 1 and self.clock() < deadline and not self._camera_lost():
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
        self._drain()
