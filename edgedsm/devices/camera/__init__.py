"""Camera drivers: one contract (``Camera``), real and simulated drivers behind it.

Open any camera from its URI (grammar in ``edgedsm.devices.camera.uri``)::

    from edgedsm.devices.camera import open_camera
    with open_camera("aravis:Aravis-Fake-GV01") as camera:
        for frame in camera.frames(10): ...

The Aravis and V4L2 drivers import their libraries only when used.
"""

from edgedsm.devices.camera.base import PIXEL_FORMATS, Backoff, Camera, EndOfStream, Region
from edgedsm.devices.camera.replay import ReplayCamera
from edgedsm.devices.camera.sim import SimulatedCamera
from edgedsm.devices.camera.uri import CameraSpec, open_camera, parse_camera_uri

__all__ = ["PIXEL_FORMATS", "Backoff", "Camera", "CameraSpec", "EndOfStream", "Region", "ReplayCamera",
           "SimulatedCamera", "open_camera", "parse_camera_uri"]
