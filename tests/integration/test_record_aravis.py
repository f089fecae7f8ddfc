"""`edgedsm record` from Aravis cameras: its in-process Fake camera and the fake GigE Vision camera
(a separate process speaking GVCP/GVSP on loopback). What the camera delivered is what `analyze`
and `replay:` read back, pixel for pixel, with the camera's own frame numbers and timestamps."""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np
import pytest
from helpers_aravis import FakeGvCamera, fake_gv_cameras, require_aravis

from edgedsm.cli import main
from edgedsm.devices.camera import open_camera
from edgedsm.estimators import s1
from edgedsm.frameio import open_frames
from edgedsm.frameio.recording import RecordingWriter
from edgedsm.frames import Frame

pytestmark = [pytest.mark.integration, pytest.mark.timeout(60)]


@pytest.fixture
def gv_factory(tmp_path) -> Iterator[Callable[..., FakeGvCamera]]:
    yield from fake_gv_cameras(tmp_path)


@pytest.fixture
def delivered(monkeypatch) -> list[Frame]:
    """Every frame the recorder was handed by the camera, kept aside (copies)."""
    kept: list[Frame] = []
    write = RecordingWriter.write

    def keeping(self, frame, laser="none"):
        kept.append(Frame(frame.pixels.copy(), frame.seq, frame.t_ns, frame.bits))
        write(self, frame, laser)

    monkeypatch.setattr(RecordingWriter, "write", keeping)
    return kept


def _reads_back(path, delivered, tmp_path):
    with open_frames(path) as reader:
        assert reader.count == len(delivered)
        assert all(np.array_equal(a, b.pixels) for a, b in zip(reader.frames(), delivered, strict=True))
        stamps = reader.stamps()
    assert stamps.seq.tolist() == [f.seq for f in delivered]
    assert stamps.t_ns.tolist() == [f.t_ns for f in delivered]
    out = tmp_path / "map.npy"
    assert main(["analyze", str(path), "--lag", "3", "-o", str(out)]) == 0
    assert np.array_equal(np.load(out), s1(np.stack([f.pixels for f in delivered]), 3))
    with open_camera(f"replay:{path}") as replay:
        assert [(f.seq, f.t_ns) for f in replay.frames()] == [(f.seq, f.t_ns) for f in delivered]


def test_record_aravis_fake_interface_mono16(tmp_path, delivered):
    require_aravis()
    config = tmp_path / "fake.toml"
    config.write_text('[device]\nname = "fake"\n\n[camera]\nuri = "aravis:Fake_1"\npixel_format = "Mono16"\n'
                      "frame_interval_s = 0.01\n")
    path = tmp_path / "fake.tif"
    assert main(["record", "-c", str(config), "-o", str(path), "--frames", "20", "--no-progress"]) == 0
    assert len(delivered) == 20 and delivered[0].pixels.dtype == np.uint16
    with open_frames(path) as reader:
        assert reader.header["pixel_format"] == "Mono16"
    _reads_back(path, delivered, tmp_path)


def test_record_the_fake_gige_vision_camera(tmp_path, gv_factory, delivered):
    fake = gv_factory()
    path = tmp_path / "gige.tif"
    assert main(["record", f"aravis:{fake.device_id}", "-o", str(path), "--frames", "15", "--no-progress"]) == 0
    assert len(delivered) == 15
    _reads_back(path, delivered, tmp_path)
