"""The camera contract: checks every camera driver must pass, real and simulated alike.

``make`` is a factory returning a new, unopened camera of your driver; each check opens and
closes what it makes. Run them all with :func:`check_camera_contract`, or one by one from
:data:`CAMERA_CHECKS` (to see each as its own test). A failed check raises ``AssertionError``
with what was expected; no pytest is needed. See docs/drivers.md.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable

import numpy as np

from edgedsm.devices.camera import Camera
from edgedsm.errors import DeviceError
from edgedsm.testing._expect import check, expect_error

CameraFactory = Callable[[], Camera]


def check_lifecycle(make: CameraFactory) -> None:
    """Unopened until opened; frames refused while closed; the context manager closes; closing twice is harmless."""
    camera = make()
    check(not camera.is_open, f"{camera!r}: open before open() was called")
    with expect_error(DeviceError, "not open", f"{camera!r}: frames() before open()"):
        next(camera.frames(1))
    with camera:
        check(camera.is_open, f"{camera!r}: not open inside its with-block")
    check(not camera.is_open, f"{camera!r}: still open after its with-block")
    camera.close()


def check_frames(make: CameraFactory, count: int = 5) -> None:
    """``count`` frames: rising seq, non-decreasing t_ns, 2-D uint8/uint16 pixels of one shape
    within their significant bits, and the ``delivered`` counter agrees."""
    with make() as camera:
        frames = list(camera.frames(count))
    check(len(frames) == count, f"{camera!r}: asked for {count} frames, got {len(frames)}")
    seqs = [f.seq for f in frames]
    check(seqs == sorted(seqs) and len(set(seqs)) == count, f"{camera!r}: seq not strictly rising: {seqs}")
    times = [f.t_ns for f in frames]
    check(all(b >= a for a, b in itertools.pairwise(times)), f"{camera!r}: t_ns goes backwards: {times}")
    check(len({f.pixels.shape for f in frames}) == 1,
          f"{camera!r}: the frame shape changes within one stream: {[f.pixels.shape for f in frames]}")
    for frame in frames:
        check(frame.pixels.ndim == 2, f"{camera!r}: pixels must be 2-D, got shape {frame.pixels.shape}")
        check(frame.pixels.dtype in (np.uint8, np.uint16),
              f"{camera!r}: pixels must be uint8 or uint16, got {frame.pixels.dtype}")
        check(1 <= frame.bits <= 16, f"{camera!r}: bits must be 1..16, got {frame.bits}")
        check(frame.pixels.dtype == np.uint16 or frame.bits <= 8,
              f"{camera!r}: {frame.bits} significant bits do not fit uint8 pixels")
        check(int(frame.pixels.max()) < 2**frame.bits,
              f"{camera!r}: pixel value {int(frame.pixels.max())} beyond {frame.bits} bits")
    check(camera.stats["delivered"] == count,
          f"{camera!r}: stats['delivered'] = {camera.stats['delivered']}, expected {count}")


def check_bad_settings_refused(make: CameraFactory) -> None:
    """A negative exposure, a zero frame interval and an unknown pixel format are DeviceErrors."""
    with make() as camera:
        with expect_error(DeviceError, "exposure", f"{camera!r}: set_exposure(-1)"):
            camera.set_exposure(-1)
        with expect_error(DeviceError, "frame interval", f"{camera!r}: set_frame_interval(0)"):
            camera.set_frame_interval(0)
        with expect_error(DeviceError, "pixel format", f"{camera!r}: set_pixel_format('RGB8')"):
            camera.set_pixel_format("RGB8")


def check_frames_after_reopen(make: CameraFactory) -> None:
    """The same camera object streams again after close() and open()."""
    camera = make()
    with camera:
        first = list(camera.frames(2))
    with camera:
        second = list(camera.frames(2))
    check(len(first) == len(second) == 2,
          f"{camera!r}: 2 frames before and after reopening, got {len(first)} and {len(second)}")


def check_frame_format(make: CameraFactory) -> None:
    """``frame_format()`` is refused while closed; once open it is None or the shape, bits and
    dtype of the frames that come."""
    camera = make()
    with expect_error(DeviceError, "not open", f"{camera!r}: frame_format() before open()"):
        camera.frame_format()
    with camera:
        said = camera.frame_format()
        frames = list(camera.frames(2))
    came = sorted({(frame.shape, frame.bits, str(frame.pixels.dtype)) for frame in frames})
    told = None if said is None else (said.shape, said.bits, str(said.dtype))
    check(told is None or came == [told], f"{camera!r}: frame_format() said {told}, the frames came as {came}")


CAMERA_CHECKS: dict[str, Callable[[CameraFactory], None]] = {
    "lifecycle": check_lifecycle,
    "frames": check_frames,
    "bad_settings_refused": check_bad_settings_refused,
    "frames_after_reopen": check_frames_after_reopen,
    "frame_format": check_frame_format,
}
"""Every camera check by name, in the order :func:`check_camera_contract` runs them."""


def check_camera_contract(make: CameraFactory) -> None:
    """Run every camera check against cameras from ``make``; the first failure raises AssertionError."""
    for camera_check in CAMERA_CHECKS.values():
        camera_check(make)
