"""V4L2 cameras (USB webcams, UVC and MIPI sensors) through OpenCV's V4L2 backend.

A thin driver: ``cv2.VideoCapture(path_or_index, cv2.CAP_V4L2)`` with OpenCV's RGB
conversion switched off, so the luminance arrives as the sensor gave it. Rules for measurement:

- **Uncompressed only.** A device that delivers a compressed format (MJPG, H264, ...) is
  refused at open: compression artefacts change the speckle statistics. Ask for a raw
  format with ``fourcc`` (GREY, Y10, Y12, Y16, YUYV, UYVY; YUYV/UYVY give their luma, or the
  red, green or blue channel asked for with ``channel``: a colour camera under a red laser).
- **Fixed exposure and gain** where the device allows: automatic exposure is switched to
  manual, white balance and autofocus off, gain pinned at its current value. What could not
  be locked is logged and listed in ``unlocked`` (OpenCV cannot reach every V4L2 control,
  e.g. automatic gain: use ``v4l2-ctl -c gain_automatic=0`` or the like where it exists).
- Exposure is V4L2's absolute exposure in units of 100 µs; timestamps are the driver's
  buffer timestamps (``CAP_PROP_POS_MSEC``, the kernel's monotonic clock) where present.
- The region is the resolution only (x = y = 0); V4L2 has no generic sensor region.

``list_devices()`` gives the ``/dev/video*`` nodes. Without a device this driver cannot be
exercised for real; ``capture_factory`` lets tests put a stand-in for ``cv2.VideoCapture``.
"""

from __future__ import annotations

import glob
import logging
import os
import time
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np

from edgedsm.devices.camera.base import Camera, Region
from edgedsm.errors import DeviceError, DeviceLost, DeviceTimeout
from edgedsm.frameio.channels import select_channel
from edgedsm.frames import Frame, FrameFormat

log = logging.getLogger(__name__)

#: Uncompressed V4L2 formats (FOURCC → significant bits) the driver can measure with.
RAW_FOURCCS = {"GREY": 8, "Y10 ": 10, "Y12 ": 12, "Y16 ": 16, "YUYV": 8, "UYVY": 8}
#: GenICam pixel format names → the V4L2 format asked for.
PIXEL_FORMAT_FOURCC = {"Mono8": "GREY", "Mono10": "Y10 ", "Mono12": "Y12 ", "Mono16": "Y16 "}
V4L2_EXPOSURE_MANUAL = 1  # V4L2_CID_EXPOSURE_AUTO value; OpenCV passes it through unchanged
EXPOSURE_UNIT_US = 100.0  # V4L2_CID_EXPOSURE_ABSOLUTE counts 100 µs


def fourcc_text(code: float) -> str:
    """The 4-character name of a FOURCC code as OpenCV reports it (a float)."""
    value = int(code)
    return "".join(chr((value >> (8 * i)) & 0xFF) for i in range(4))


def fourcc_code(text: str) -> int:
    return int(cv2.VideoWriter.fourcc(*text.ljust(4)[:4]))


def check_uncompressed(fourcc: str, device: str) -> int:
    """Significant bits of a raw format; ``DeviceError`` for a compressed or unknown one."""
    if fourcc in RAW_FOURCCS:
        return RAW_FOURCCS[fourcc]
    shown = fourcc.strip() or repr(fourcc)
    raise DeviceError(f"{device} delivers {shown}, a compressed or unsupported format: refused for "
                      f"measurement (compression alters the speckle statistics). Ask for an uncompressed "
                      f"one, e.g. v4l2:{device}?fourcc=GREY; the device lists its formats with "
                      f"'v4l2-ctl -d {device} --list-formats'")


COLOUR_CHANNELS = ("red", "green", "blue")
_YUV_TO_BGR = {"YUYV": cv2.COLOR_YUV2BGR_YUYV, "UYVY": cv2.COLOR_YUV2BGR_UYVY}


def to_mono(image: np.ndarray, fourcc: str, width: int, height: int, channel: str | None = None) -> np.ndarray:
    """The luminance (or the colour ``channel`` asked for) of one V4L2 frame as delivered by
    OpenCV with RGB conversion off.

    OpenCV hands back either a decoded 2-D image, a (H, W, 2) YUYV/UYVY image or the raw
    buffer as one row of bytes, depending on the format and its version; all become a 2-D
    uint8 (GREY, YUYV, UYVY) or little-endian-decoded uint16 (Y10, Y12, Y16) array.
    ``channel`` red, green or blue converts YUYV/UYVY to B, G, R (OpenCV) and keeps that one.
    Raises ``DeviceError`` for data that do not fit the format.
    """
    if channel in COLOUR_CHANNELS:
        return _colour_channel(image, fourcc, width, height, channel)  # type: ignore[arg-type]
    if image.ndim == 2 and image.shape == (height, width) and image.dtype in (np.uint8, np.uint16):
        return image
    luma_channel = 1 if fourcc == "UYVY" else 0
    if image.ndim == 3 and image.shape[:2] == (height, width):
        if image.shape[2] == 2 and fourcc in ("YUYV", "UYVY"):
            return np.ascontiguousarray(image[:, :, luma_channel])
        if image.shape[2] == 3:  # conversion happened anyway: not raw, but still luminance
            return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    raw = image.reshape(-1).view(np.uint8)
    pixels = width * height
    if fourcc == "GREY" and raw.size >= pixels:
        return raw[:pixels].reshape(height, width).copy()
    if fourcc in ("Y10 ", "Y12 ", "Y16 ") and raw.size >= 2 * pixels:
        return raw[:2 * pixels].view("<u2").reshape(height, width).astype(np.uint16)
    if fourcc in ("YUYV", "UYVY") and raw.size >= 2 * pixels:
        return raw[luma_channel:2 * pixels:2].reshape(height, width).copy()
    raise DeviceError(f"a {fourcc.strip()} frame of {width}x{height} cannot come as {image.dtype} "
                      f"{image.shape}")


def _colour_channel(image: np.ndarray, fourcc: str, width: int, height: int, channel: str) -> np.ndarray:
    if image.ndim == 3 and image.shape == (height, width, 3):  # converted by OpenCV anyway: B, G, R
        return select_channel(image, channel, "bgr")
    if fourcc not in _YUV_TO_BGR:
        raise DeviceError(f"a {fourcc.strip()} frame is monochrome: it has no {channel} channel")
    raw = image.reshape(-1).view(np.uint8)
    if raw.size < 2 * width * height:
        raise DeviceError(f"a {fourcc.strip()} frame of {width}x{height} cannot come as {image.dtype} {image.shape}")
    packed = raw[:2 * width * height].reshape(height, width, 2)
    return select_channel(cv2.cvtColor(packed, _YUV_TO_BGR[fourcc]), channel, "bgr")


def list_devices() -> list[str]:
    """The V4L2 video device nodes present now (``/dev/video*``), in numeric order."""
    def number(path: str) -> int:
        suffix = path.removeprefix("/dev/video")
        return int(suffix) if suffix.isdigit() else 1 << 30

    return sorted(glob.glob("/dev/video[0-9]*"), key=number)


class V4L2Camera(Camera):
    """A V4L2 device by path (``/dev/video0``, ``/dev/v4l/by-id/...``) or index (0)."""

    kind = "v4l2"

    def __init__(self, device: str | int, fourcc: str | None = None, width: int | None = None,
                 height: int | None = None, channel: str | None = None,
                 capture_factory: Callable[..., Any] | None = None) -> None:
        super().__init__(f"V4L2 camera {device}")
        if fourcc is not None:
            fourcc = fourcc.upper().ljust(4)
            check_uncompressed(fourcc, str(device))
        self.device = device
        self.fourcc = fourcc
        self.width = width
        self.height = height
        self.channel = channel
        self.unlocked: list[str] = []
        self._factory = capture_factory or cv2.VideoCapture
        self._capture: Any = None
        self._format = ""
        self._bits = 8
        self._size = (0, 0)
        self._seq = 0

    @property
    def path(self) -> str:
        return f"/dev/video{self.device}" if isinstance(self.device, int) else str(self.device)

    def _do_open(self) -> None:
        path = self.path
        if not os.path.exists(path):
            present = ", ".join(list_devices()) or "none"
            raise DeviceError(f"{self.description}: no such device {path} (V4L2 devices present: {present}); "
                              f"is the camera plugged in?")
        if not os.access(path, os.R_OK | os.W_OK):
            raise DeviceError(f"{self.description}: no permission to open {path}; add the service user "
                              f"to the 'video' group")
        if self._factory is cv2.VideoCapture and not cv2.videoio_registry.hasBackend(cv2.CAP_V4L2):
            raise DeviceError("this OpenCV build has no V4L2 backend")
        capture = self._factory(self.device if isinstance(self.device, int) else path, cv2.CAP_V4L2)
        if not capture.isOpened():
            capture.release()
            raise DeviceError(f"{self.description}: {path} exists but cannot be opened as a V4L2 capture "
                              f"device (busy, or a metadata node?)")
        self._capture = capture
        try:
            self._setup()
        except BaseException:
            self._do_close()
            raise

    def _setup(self) -> None:
        capture = self._capture
        capture.set(cv2.CAP_PROP_CONVERT_RGB, 0)  # raw data, no colour conversion
        if self.fourcc is not None:
            capture.set(cv2.CAP_PROP_FOURCC, fourcc_code(self.fourcc))
        if self.width is not None:
            capture.set(cv2.CAP_PROP_FRAME_WIDTH, self.width)
        if self.height is not None:
            capture.set(cv2.CAP_PROP_FRAME_HEIGHT, self.height)
        self._read_format(self.fourcc)
        self._lock_controls()

    def _read_format(self, expected: str | None) -> None:
        """Read back format and size; refuse a compressed format or one other than ``expected``."""
        capture = self._capture
        fourcc = fourcc_text(capture.get(cv2.CAP_PROP_FOURCC))
        if expected is not None and fourcc != expected:
            raise DeviceError(f"{self.description}: asked for {expected.strip()}, the device gives "
                              f"{fourcc.strip() or 'nothing'}")
        self._bits = check_uncompressed(fourcc, self.path)
        if self.channel in COLOUR_CHANNELS and fourcc not in _YUV_TO_BGR:
            raise DeviceError(f"{self.description}: channel={self.channel} needs a colour format (YUYV or UYVY); "
                              f"the device gives {fourcc.strip()}, which is monochrome")
        self._format = fourcc
        self._size = (int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)), int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)))

    def _lock_controls(self) -> None:
        """Manual exposure, fixed gain, no auto white balance or focus; note what refused."""
        capture = self._capture
        self.unlocked = []
        wanted = [("exposure", cv2.CAP_PROP_AUTO_EXPOSURE, V4L2_EXPOSURE_MANUAL),
                  ("white balance", cv2.CAP_PROP_AUTO_WB, 0), ("autofocus", cv2.CAP_PROP_AUTOFOCUS, 0)]
        gain = capture.get(cv2.CAP_PROP_GAIN)
        if gain >= 0:  # OpenCV answers -1 (or 0 and False on set) for a control the device lacks
            wanted.append(("gain", cv2.CAP_PROP_GAIN, gain))
        for name, prop, value in wanted:
            if not capture.set(prop, value) or capture.get(prop) != value:
                self.unlocked.append(name)
        if self.unlocked:
            log.warning("%s: could not fix %s; the device may adjust them by itself", self.description,
                        ", ".join(self.unlocked))

    def _do_close(self) -> None:
        if self._capture is not None:
            capture, self._capture = self._capture, None
            capture.release()

    def _do_grab(self, timeout_s: float) -> Frame | None:
        capture = self._capture
        capture.set(cv2.CAP_PROP_READ_TIMEOUT_MSEC, max(1, round(timeout_s * 1000)))  # where supported
        ok, image = capture.read()
        if not ok or image is None:
            if not os.path.exists(self.path):
                raise DeviceLost(f"{self.description}: {self.path} disappeared")
            raise DeviceTimeout(f"{self.description}: no frame within {timeout_s:g} s")
        width, height = self._size
        try:
            pixels = to_mono(image, self._format, width, height, self.channel)
        except DeviceError as exc:
            log.debug("%s: %s", self.description, exc)
            self._dropped("corrupt")
            return None
        stamp_ms = capture.get(cv2.CAP_PROP_POS_MSEC)
        t_ns = round(stamp_ms * 1e6) if stamp_ms > 0 else time.monotonic_ns()
        seq = self._seq
        self._seq += 1
        return Frame(pixels, seq, t_ns, self._bits)

    def _do_set_exposure(self, microseconds: float) -> float:
        capture = self._capture
        if not capture.set(cv2.CAP_PROP_EXPOSURE, microseconds / EXPOSURE_UNIT_US):
            raise DeviceError(f"{self.description}: exposure cannot be set on this device")
        return float(capture.get(cv2.CAP_PROP_EXPOSURE)) * EXPOSURE_UNIT_US

    def _do_set_frame_interval(self, seconds: float) -> float:
        capture = self._capture
        if not capture.set(cv2.CAP_PROP_FPS, 1.0 / seconds):
            raise DeviceError(f"{self.description}: frame rate cannot be set on this device")
        fps = capture.get(cv2.CAP_PROP_FPS)
        return 1.0 / fps if fps > 0 else seconds

    def _do_frame_format(self) -> FrameFormat:
        width, height = self._size  # every frame is cut to the negotiated format (to_mono)
        return FrameFormat.of((height, width), self._bits)

    def _do_set_region(self, region: Region) -> Region:
        if region.x or region.y:
            raise DeviceError(f"{self.description}: V4L2 sets the resolution only; the region must start at 0, 0")
        capture = self._capture
        capture.set(cv2.CAP_PROP_FRAME_WIDTH, region.width)
        capture.set(cv2.CAP_PROP_FRAME_HEIGHT, region.height)
        self._read_format(self._format)
        return Region(0, 0, *self._size)

    def _do_set_pixel_format(self, pixel_format: str) -> str:
        fourcc = PIXEL_FORMAT_FOURCC.get(pixel_format)
        if fourcc is None:
            raise DeviceError(f"{self.description}: pixel format {pixel_format} has no V4L2 counterpart; "
                              f"use one of {', '.join(PIXEL_FORMAT_FOURCC)}")
        self._capture.set(cv2.CAP_PROP_FOURCC, fourcc_code(fourcc))
        self._read_format(fourcc)
        self.fourcc = fourcc  # asked for again after a reconnect
        return pixel_format
