"""Aravis driver logic that needs no camera: frame-id unwrapping, arguments, a missing Aravis."""

from __future__ import annotations

import sys

import pytest

from edgedsm.devices.camera import aravis
from edgedsm.devices.camera.aravis import AravisCamera, unwrap_frame_id
from edgedsm.errors import DeviceError


def test_frame_ids_unwrap_across_the_16_bit_wrap():
    seq, raw_ids, seqs = -1, [65533, 65534, 65535, 1, 2, 5], []
    previous = None
    for raw in raw_ids:
        seq = unwrap_frame_id(previous, seq, raw)
        previous = raw
        seqs.append(seq)
    assert seqs == [65533, 65534, 65535, 65536, 65537, 65540]  # the gap 2 -> 5 stays a gap


def test_a_restarted_camera_continues_the_sequence():
    assert unwrap_frame_id(100, 100, 3) == 101          # camera restarted: never back, never twice
    assert unwrap_frame_id(70000, 9, 70005) == 14       # 64-bit ids (GigE Vision 2) simply grow
    assert unwrap_frame_id(None, -1, 42) == 42


def test_arguments_are_checked():
    with pytest.raises(DeviceError, match="buffers"):
        AravisCamera("cam", buffers=0)
    with pytest.raises(DeviceError, match="packet_size"):
        AravisCamera("cam", packet_size="jumbo")


def test_missing_aravis_names_what_to_install(monkeypatch):
    monkeypatch.setattr(aravis, "_aravis", None)
    monkeypatch.setitem(sys.modules, "gi", None)  # "import gi" now fails as on a bare machine
    with pytest.raises(DeviceError) as caught:
        AravisCamera("Fake_1").open()
    message = str(caught.value)
    for needed in ("gir1.2-aravis-0.8", "aravis-tools", "PyGObject<3.51", "libgirepository1.0-dev"):
        assert needed in message
    with pytest.raises(DeviceError, match=r"gir1\.2-aravis-0\.8"):
        aravis.list_cameras()


class ListedDevices:
    """Aravis' device-list functions over a fixed list (what discovery found), counting updates."""

    def __init__(self, devices: list[tuple[str, str, str, str, str]]) -> None:
        self.devices = devices  # (id, serial, physical id, protocol, address)
        self.updates = 0

    def update_device_list(self) -> None:
        self.updates += 1

    def get_n_devices(self) -> int:
        return len(self.devices)

    def get_device_id(self, i: int) -> str:
        return self.devices[i][0]

    def get_device_serial_nbr(self, i: int) -> str:
        return self.devices[i][1]

    def get_device_physical_id(self, i: int) -> str:
        return self.devices[i][2]

    def get_device_protocol(self, i: int) -> str:
        return self.devices[i][3]

    def get_device_address(self, i: int) -> str:
        return self.devices[i][4]


def test_a_gige_camera_named_by_id_is_opened_by_its_address(monkeypatch):
    listed = ListedDevices([("Fake_1", "1", "", "Fake", ""),
                            ("Basler-2123", "2123", "00:30:53:aa:bb:cc", "GigEVision", "192.168.10.21"),
                            ("Aravis-Fake-EDG1", "EDG1", "00:00:00:00:00:01", "GigEVision", "127.0.0.1")])
    monkeypatch.setattr(aravis, "_aravis", (listed, None))
    assert AravisCamera("Aravis-Fake-EDG1")._open_target() == "127.0.0.1"
    assert AravisCamera("2123")._open_target() == "192.168.10.21"                  # by serial number
    assert AravisCamera("00:30:53:aa:bb:cc")._open_target() == "192.168.10.21"     # by MAC address
    assert AravisCamera("Fake_1")._open_target() == "Fake_1"                       # not GigE: by id
    assert AravisCamera(None)._open_target() == "Fake_1"                           # the first found
    assert AravisCamera("my-user-name")._open_target() == "my-user-name"           # left to Aravis
    assert listed.updates == 6, "the device list is fresh at every open (reconnection included)"
    assert AravisCamera("192.168.10.21")._open_target() == "192.168.10.21"
    assert listed.updates == 6, "an address needs no discovery"
