"""Camera drivers: one contract (``Camera``), real and simulated drivers behind it."""

from edgedsm.devices.camera.base import PIXEL_FORMATS, Backoff, Camera, EndOfStream, Region
from edgedsm.devices.camera.replay import ReplayCamera
from edgedsm.devices.camera.sim import SimulatedCamera

__all__ = ["PIXEL_FORMATS", "Backoff", "Camera", "EndOfStream", "Region", "ReplayCamera", "SimulatedCamera"]
