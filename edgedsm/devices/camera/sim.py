"""A simulated camera built on the speckle simulator, coupled to the laser.

With the laser on it delivers speckle; with it off, what the sensor sees without the laser
(ambient light and its shot noise only, or black without ambient light). The surface keeps
evolving while the laser is off, as a real one would. Frames are paced at the scene's Δt
times ``time_scale`` (0 = as fast as possible); timestamps are the camera's own clock
(frame index × Δt), so they are exact whatever the pacing.
"""

from __future__ import annotations

from collections.abc import Callable

from edgedsm.devices.camera.base import Camera, Region, pace
from edgedsm.errors import DeviceError, DeviceLost
from edgedsm.frames import Frame, FrameFormat
from edgedsm.sim import Scene, Simulator


class SimulatedCamera(Camera):
    """Camera stand-in for tests and demos.

    ``illuminated`` tells whether the laser is on (e.g. a relay's state); None means always on.
    Fault injection for tests: ``lose_after`` frames the device is lost once (``DeviceLost``),
    and every ``corrupt_every``-th buffer is dropped as corrupt.
    """

    kind = "sim"

    def __init__(self, scene: Scene, illuminated: Callable[[], bool] | None = None, time_scale: float = 1.0,
                 lose_after: int | None = None, corrupt_every: int | None = None, precision: str = "single",
                 description: str | None = None) -> None:
        super().__init__(description or f"simulated camera {scene.scene.size}x{scene.scene.size}")
        if time_scale < 0:
            raise DeviceError("time_scale must be >= 0")
        self.scene = scene
        self.illuminated = illuminated
        self.time_scale = time_scale
        self.lose_after = lose_after
        self.corrupt_every = corrupt_every
        self._precision = precision
        self._simulator: Simulator | None = None
        self._dt = scene.scene.dt
        self._seq = 0
        self._next_due = 0.0
        self._exposure_us = 1000.0
        self._lost_once = False

    @property
    def paced(self) -> bool:
        return self.time_scale > 0

    @property
    def bits(self) -> int:
        return self.scene.detector.bits if self.scene.detector is not None else 16

    def _do_open(self) -> None:
        if self.scene.detector is None:
            raise DeviceError("a simulated camera needs a scene with a [detector] table (integer frames)")
        if self._simulator is None:
            self._simulator = Simulator(self.scene, precision=self._precision)  # type: ignore[arg-type]

    def _do_close(self) -> None:
        pass  # the simulated surface survives a reconnect, like a real one

    def _do_start(self) -> None:
        self._next_due = 0.0

    def _do_grab(self, timeout_s: float) -> Frame | None:
        assert self._simulator is not None
        if self.lose_after is not None and not self._lost_once and self._seq >= self.lose_after:
            self._lost_once = True
            raise DeviceLost(f"{self.description}: simulated loss after {self._seq} frames")
        if self.time_scale > 0:
            self._next_due = pace(self._next_due, self._dt * self.time_scale)
        laser_on = True if self.illuminated is None else bool(self.illuminated())
        pixels = self._simulator.next_frame(laser_on=laser_on)
        seq = self._seq
        self._seq += 1
        if self.corrupt_every and (seq + 1) % self.corrupt_every == 0:
            self._dropped("corrupt")
            return None
        return Frame(pixels, seq, round(seq * self._dt * 1e9), self.bits)

    def _do_frame_format(self) -> FrameFormat:
        size = self.scene.scene.size
        return FrameFormat.of((size, size), self.bits)

    def _do_set_exposure(self, microseconds: float) -> float:
        self._exposure_us = microseconds  # the model has no motion blur: recorded only
        return microseconds

    def _do_set_frame_interval(self, seconds: float) -> float:
        self._dt = seconds
        return seconds

    def _do_set_region(self, region: Region) -> Region:
        size = self.scene.scene.size
        if (region.x, region.y, region.width, region.height) != (0, 0, size, size):
            raise DeviceError(f"{self.description}: only the full {size}x{size} region is simulated")
        return region

    @property
    def delivers(self) -> str:
        """The one pixel format the scene's detector delivers (the only one it can be set to)."""
        return "Mono8" if self.bits <= 8 else "Mono16"

    def _do_set_pixel_format(self, pixel_format: str) -> str:
        if pixel_format != self.delivers:
            raise DeviceError(f"{self.description}: the scene's {self.bits}-bit detector delivers {self.delivers}")
        return pixel_format
