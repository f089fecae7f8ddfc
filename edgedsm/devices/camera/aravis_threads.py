"""Background threads of the Aravis driver, for calls that may block on a camera that is gone.

A GigE Vision camera that lost power answers nothing: each control read or write waits for
its retries (2.5 s), and dropping the last reference of its device blocks for 5-8 s. Those
waits happen here, never in a grab or a reconnection.
"""

from __future__ import annotations

import logging
import threading
from typing import Any

from edgedsm.errors import DeviceLost

log = logging.getLogger(__name__)

#: GigE Vision Control Channel Privilege register: bit 0 exclusive, bit 1 control access.
GVCP_CCP_REGISTER = 0x0A00


def release_in_background(objects: list[Any]) -> None:
    """Drop the last references of a lost camera's objects on a reaper thread."""
    threading.Thread(target=unreference, args=(objects,), name="aravis-release", daemon=True).start()


def unreference(objects: list[Any]) -> None:
    """Reaper thread body: drop the last references (the wait happens in GLib, GIL released)."""
    try:
        objects.clear()
    except Exception:  # never let a finalizer's trouble escape a background thread
        log.exception("releasing a lost Aravis camera failed")


class AliveCheck:
    """One control-channel read on a helper thread, telling a quiet camera from a lost one.

    A GigE Vision camera is asked for its Control Channel Privilege register: no answer means
    it is gone; an answer without our control bits means it restarted meanwhile and no longer
    streams to us. Either way the camera is lost (``lost`` is set). Other cameras are asked
    for their width. The thread keeps its own references: the grab may give up on it, and
    the driver may close and reopen, while it still waits.
    """

    def __init__(self, description: str, camera: Any, device: Any, error_type: type[Exception]) -> None:
        self.answered = threading.Event()
        self.lost: DeviceLost | None = None
        self._description = description
        self._error_type = error_type  # GLib.Error
        threading.Thread(target=self._run, args=([camera, device],), name="aravis-alive-check", daemon=True).start()

    def _run(self, objects: list[Any]) -> None:
        camera, device = objects
        try:
            if camera.is_gv_device():
                if not device.read_register(GVCP_CCP_REGISTER) & 0x3:
                    self.lost = DeviceLost(f"{self._description}: the camera restarted (we no longer control it)")
            else:
                camera.get_integer("Width")
        except self._error_type as exc:
            self.lost = DeviceLost(f"{self._description}: no frames and no answer ({getattr(exc, 'message', exc)})")
        except Exception as exc:  # never let a background thread's trouble pass unseen
            self.lost = DeviceLost(f"{self._description}: the control-channel check failed ({exc})")
        if self.lost is None:
            self.answered.set()
        del camera, device
        unreference(objects)  # may be the last references of a lost camera: may block here
