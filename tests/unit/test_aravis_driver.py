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
