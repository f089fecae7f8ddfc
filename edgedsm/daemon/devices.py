"""The devices a daemon config names, built from the specs the config parsed: used by the
service, by a reload's checks and by the benchmarks that run the real pipeline."""

from __future__ import annotations

from edgedsm.config import DaemonConfig
from edgedsm.devices.camera.base import Camera
from edgedsm.devices.camera.sim import SimulatedCamera
from edgedsm.devices.camera.uri import open_camera
from edgedsm.devices.laser import LaserRelay, SimulatedRelay


def open_camera_for(config: DaemonConfig) -> Camera:
    """The configured camera, built from the spec the config parsed (paths already resolved);
    it touches no device until opened."""
    return open_camera(config.camera.spec)


def couple_simulated_laser(camera: Camera, relay: LaserRelay | None) -> None:
    """A simulated camera sees speckle only while the simulated laser's contact is closed."""
    if isinstance(camera, SimulatedCamera) and isinstance(relay, SimulatedRelay):
        board = relay.board
        camera.illuminated = lambda: board.is_on
