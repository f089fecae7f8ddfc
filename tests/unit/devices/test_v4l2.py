"""V4L2 driver without a device: missing devices, compressed formats, frame decoding, and the
camera contract against a stand-in for ``cv2.VideoCapture`` that behaves like OpenCV's V4L2 backend."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from edgedsm.devices.camera.v4l2 import (
    V4L2Camera,
    check_uncompressed,
    fourcc_code,
    fourcc_text,
    list_devices,
    to_mono,
)
from edgedsm.errors import DeviceError, DeviceLost
from edgedsm.testing import check_camera_contract


class FakeCapture:
    """Answers get/set like OpenCV's V4L2 backend for a device with the given properties."""

    def __init__(self, fourcc: str = "GREY", width: int = 8, height: int = 6, controls: bool = True,
                 opened: bool = True, raw_rows: bool = False) -> None:
        self.props: dict[int, float] = {cv2.CAP_PROP_FOURCC: fourcc_code(fourcc), cv2.CAP_PROP_FRAME_WIDTH: width,
                                        cv2.CAP_PROP_FRAME_HEIGHT: height, cv2.CAP_PROP_FPS: 30.0}
        if controls:
            self.props.update({cv2.CAP_PROP_AUTO_EXPOSURE: 3, cv2.CAP_PROP_EXPOSURE: 100, cv2.CAP_PROP_GAIN: 4,
                               cv2.CAP_PROP_AUTO_WB: 1, cv2.CAP_PROP_AUTOFOCUS: 1})
        self.opened = opened
        self.raw_rows = raw_rows
        self.released = False
        self.reads = 0
        self.args: tuple = ()

    def __call__(self, *args):  # used as the capture factory
        self.args = args
        return self

    def isOpened(self) -> bool:  # noqa: N802 - OpenCV's name
        return self.opened

    def release(self) -> None:
        self.released = True

    def get(self, prop: int) -> float:
        return float(self.props.get(prop, -1.0 if prop == cv2.CAP_PROP_GAIN else 0.0))

    def set(self, prop: int, value: float) -> bool:
        if prop in (cv2.CAP_PROP_CONVERT_RGB, cv2.CAP_PROP_READ_TIMEOUT_MSEC):
            return True
        if prop not in self.props:
            return False
        self.props[prop] = value
        return True

    def read(self):
        self.reads += 1
        width, height = int(self.props[cv2.CAP_PROP_FRAME_WIDTH]), int(self.props[cv2.CAP_PROP_FRAME_HEIGHT])
        self.props[cv2.CAP_PROP_POS_MSEC] = 1000.0 + 33.3 * self.reads
        image = (np.arange(width * height, dtype=np.uint8) + self.reads).reshape(height, width)
        return True, image.reshape(1, -1) if self.raw_rows else image


@pytest.fixture
def node(tmp_path):
    """A file that stands in for the device node (it exists and is readable and writable)."""
    path = tmp_path / "video9"
    path.write_bytes(b"")
    return str(path)


def test_missing_device_gives_a_clear_error():
    camera = V4L2Camera("/dev/video-that-does-not-exist")
    with pytest.raises(DeviceError, match=r"no such device /dev/video-that-does-not-exist .*plugged in"):
        camera.open()
    assert not camera.is_open
    with pytest.raises(DeviceError, match="no such device /dev/video97"):
        V4L2Camera(97).open()


def test_device_that_cannot_be_opened(node):
    capture = FakeCapture(opened=False)
    with pytest.raises(DeviceError, match="cannot be opened as a V4L2 capture device"):
        V4L2Camera(node, capture_factory=capture).open()
    assert capture.released and capture.args == (node, cv2.CAP_V4L2)


@pytest.mark.parametrize("fourcc", ["MJPG", "H264", "JPEG"])
def test_compressed_formats_are_refused_for_measurement(node, fourcc):
    capture = FakeCapture(fourcc=fourcc)
    with pytest.raises(DeviceError, match=f"delivers {fourcc}, a compressed .*fourcc=GREY"):
        V4L2Camera(node, capture_factory=capture).open()
    assert capture.released  # nothing left open
    with pytest.raises(DeviceError, match="compressed"):
        V4L2Camera(node, fourcc="MJPG")


def test_asked_format_that_the_device_ignores_is_refused(node):
    capture = FakeCapture(fourcc="YUYV")
    capture.set = lambda prop, value: prop != cv2.CAP_PROP_FOURCC  # the device keeps YUYV
    with pytest.raises(DeviceError, match="asked for GREY, the device gives YUYV"):
        V4L2Camera(node, fourcc="GREY", capture_factory=capture).open()


def test_exposure_white_balance_focus_and_gain_are_locked(node):
    capture = FakeCapture()
    with V4L2Camera(node, capture_factory=capture) as camera:
        assert camera.unlocked == []
        assert capture.props[cv2.CAP_PROP_AUTO_EXPOSURE] == 1  # V4L2_EXPOSURE_MANUAL
        assert capture.props[cv2.CAP_PROP_AUTO_WB] == 0 and capture.props[cv2.CAP_PROP_AUTOFOCUS] == 0
        assert camera.set_exposure(2500) == 2500  # in units of 100 µs on the wire
        assert capture.props[cv2.CAP_PROP_EXPOSURE] == 25
        assert camera.set_frame_interval(0.05) == pytest.approx(0.05)


def test_controls_the_device_lacks_are_reported(node, caplog):
    with V4L2Camera(node, capture_factory=FakeCapture(controls=False)) as camera:
        assert camera.unlocked == ["exposure", "white balance", "autofocus"]
    assert "could not fix exposure" in caplog.text


@pytest.mark.parametrize("raw_rows", [False, True])
def test_contract_against_a_stand_in_capture(node, raw_rows):
    check_camera_contract(lambda: V4L2Camera(node, capture_factory=FakeCapture(raw_rows=raw_rows)))
    with V4L2Camera(node, capture_factory=FakeCapture(raw_rows=raw_rows)) as camera:
        frame = next(camera.frames(1))
    assert frame.pixels.shape == (6, 8) and frame.bits == 8
    assert frame.t_ns == round(1033.3 * 1e6)  # the buffer timestamp


def test_vanished_device_is_lost(node, tmp_path):
    capture = FakeCapture()
    capture.read = lambda: (False, None)
    with V4L2Camera(node, capture_factory=capture) as camera:
        (tmp_path / "video9").unlink()
        with pytest.raises(DeviceLost, match="disappeared"):
            next(camera.frames(1))


def test_region_and_pixel_format(node):
    capture = FakeCapture()
    with V4L2Camera(node, capture_factory=capture) as camera:
        from edgedsm.devices.camera import Region

        assert camera.set_region(Region(0, 0, 4, 2)) == Region(0, 0, 4, 2)
        with pytest.raises(DeviceError, match="must start at 0, 0"):
            camera.set_region(Region(1, 0, 4, 2))
        assert camera.set_pixel_format("Mono16") == "Mono16" and fourcc_text(capture.props[6]) == "Y16 "
        with pytest.raises(DeviceError, match="no V4L2 counterpart"):
            camera.set_pixel_format("Mono12p")


def test_to_mono_for_each_way_opencv_hands_frames_back():
    grey = np.arange(12, dtype=np.uint8).reshape(3, 4)
    assert to_mono(grey, "GREY", 4, 3) is grey
    np.testing.assert_array_equal(to_mono(grey.reshape(1, -1), "GREY", 4, 3), grey)
    y16 = np.array([[0x0102, 0xFFFF]], dtype="<u2")
    assert to_mono(y16.view(np.uint8).reshape(1, -1), "Y16 ", 2, 1).tolist() == [[0x0102, 0xFFFF]]
    yuyv = np.array([[[10, 128], [20, 120]]], dtype=np.uint8)  # Y0 U Y1 V
    assert to_mono(yuyv, "YUYV", 2, 1).tolist() == [[10, 20]]
    assert to_mono(yuyv.reshape(1, -1), "YUYV", 2, 1).tolist() == [[10, 20]]
    uyvy = np.array([[128, 10, 120, 20]], dtype=np.uint8)  # U Y0 V Y1
    assert to_mono(uyvy, "UYVY", 2, 1).tolist() == [[10, 20]]
    bgr = np.full((1, 2, 3), 100, dtype=np.uint8)
    assert to_mono(bgr, "YUYV", 2, 1).tolist() == [[100, 100]]
    with pytest.raises(DeviceError, match="cannot come as"):
        to_mono(np.zeros((1, 5), np.uint8), "GREY", 4, 3)


def test_fourcc_helpers():
    assert fourcc_text(fourcc_code("MJPG")) == "MJPG" and fourcc_text(fourcc_code("Y16")) == "Y16 "
    assert check_uncompressed("Y12 ", "/dev/video0") == 12
    assert all(path.startswith("/dev/video") for path in list_devices())


def test_yuyv_gives_the_colour_channel_asked_for(node):
    height, width = 2, 4
    packed = np.empty((height, width, 2), np.uint8)
    packed[..., 0] = 120  # Y
    packed[:, 0::2, 1], packed[:, 1::2, 1] = 90, 200  # U low, V high: a red light
    red, blue = to_mono(packed, "YUYV", width, height, "red"), to_mono(packed, "YUYV", width, height, "blue")
    assert red.shape == (height, width) and red.min() > 200 and blue.max() < 70  # BT.601: R ≈ 221-236, B ≈ 44-53
    assert np.array_equal(to_mono(packed.reshape(1, -1), "YUYV", width, height, "red"), red)  # as one raw row
    assert np.array_equal(to_mono(packed, "YUYV", width, height, "luma"), packed[..., 0])
    with pytest.raises(DeviceError, match="monochrome"):
        to_mono(np.zeros((height, width), np.uint8), "GREY", width, height, "red")
    with pytest.raises(DeviceError, match="channel=red needs a colour format"):
        V4L2Camera(node, channel="red", capture_factory=FakeCapture("GREY")).open()
