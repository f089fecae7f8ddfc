"""The Aravis driver against Aravis' in-process Fake camera and a real GigE Vision fake camera.

``arv-fake-gv-camera-0.8 -i 127.0.0.1`` runs as a separate process and speaks real GigE Vision
(GVCP control, GVSP stream over UDP) on loopback: acquisition, packet loss (its ``-r``
option), the process killed (DeviceLost) and restarted (reconnection). Aravis and the fake
camera come from the Debian packages that scripts/test.sh installs; when they are missing,
these tests fail and say so rather than skip. Every test bounds its own time.
"""

from __future__ import annotations

import itertools
import os
import shutil
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from edgedsm.cli import main
from edgedsm.devices.camera import Backoff, Region
from edgedsm.devices.camera.aravis import AravisCamera, list_cameras, load_aravis
from edgedsm.devices.camera.uri import open_camera
from edgedsm.errors import DeviceError, DeviceLost, DeviceTimeout
from edgedsm.testing import check_camera_contract

pytestmark = pytest.mark.integration

FAKE_BINARY = "arv-fake-gv-camera-0.8"
ADDRESS = "127.0.0.1"
DISCOVERY_TIMEOUT_S = 10.0


def require_aravis() -> None:
    try:
        load_aravis()
    except DeviceError as exc:
        pytest.fail(f"Aravis is required for these tests (scripts/test.sh installs it): {exc}")


class FakeGvCamera:
    """One ``arv-fake-gv-camera-0.8`` process on loopback with its own serial number."""

    def __init__(self, log_dir: Path, serial: str, lost_per_thousand: int = 0) -> None:
        self.serial = serial
        self.device_id = f"Aravis-Fake-{serial}"
        self.lost_per_thousand = lost_per_thousand
        self.log_path = log_dir / f"fake-gv-{serial}.log"
        self.process: subprocess.Popen[bytes] | None = None

    def start(self, wait: bool = True) -> FakeGvCamera:
        """Start the process; ``wait`` until Aravis discovers it (bounded)."""
        binary = shutil.which(FAKE_BINARY)
        if binary is None:
            pytest.fail(f"{FAKE_BINARY} not found: install the Debian package aravis-tools (scripts/test.sh does)")
        args = [binary, "-i", ADDRESS, "-s", self.serial]
        if self.lost_per_thousand:
            args += ["-r", str(self.lost_per_thousand)]
        with self.log_path.open("ab") as log:
            self.process = subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT)
        if wait:
            self.wait_discoverable()
        return self

    def wait_discoverable(self) -> None:
        deadline = time.monotonic() + DISCOVERY_TIMEOUT_S
        while time.monotonic() < deadline:
            assert self.process is not None
            if self.process.poll() is not None:
                pytest.fail(f"{FAKE_BINARY} exited with {self.process.returncode}: {self.log()}")
            if any(info.device_id == self.device_id for info in list_cameras()):
                return
        pytest.fail(f"{self.device_id} not discoverable within {DISCOVERY_TIMEOUT_S} s: {self.log()}")

    def kill(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.kill()
            self.process.wait(timeout=10)
        self.process = None

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")[-2000:] if self.log_path.exists() else ""


@pytest.fixture
def gv_factory(tmp_path) -> Iterator:
    """Starts fake GigE Vision cameras on loopback; kills every one of them afterwards."""
    require_aravis()
    started: list[FakeGvCamera] = []
    already = [info for info in list_cameras() if info.address == ADDRESS]
    if already:
        pytest.fail(f"a camera already answers on {ADDRESS} ({already[0].device_id}); stop it first "
                    f"(pgrep -a {FAKE_BINARY[:15]})")

    def make(lost_per_thousand: int = 0) -> FakeGvCamera:
        camera = FakeGvCamera(tmp_path, f"EDG{os.getpid() % 100000}", lost_per_thousand)
        started.append(camera)
        return camera.start()

    yield make
    for camera in started:
        camera.kill()


# -- Aravis' in-process Fake interface ------------------------------------------------------

@pytest.mark.timeout(30)
def test_fake_interface_contract():
    require_aravis()
    check_camera_contract(lambda: AravisCamera("Fake_1"))


@pytest.mark.timeout(30)
def test_fake_interface_settings_and_formats():
    require_aravis()
    with open_camera("aravis:Fake_1?buffers=4") as camera:
        assert camera.set_frame_interval(0.002) == pytest.approx(0.002)
        assert camera.set_exposure(800) == pytest.approx(800)
        assert camera.set_region(Region(8, 4, 64, 32)) == Region(8, 4, 64, 32)
        assert camera.set_pixel_format("Mono16") == "Mono16"
        with pytest.raises(DeviceError, match=r"Mono12p not offered; this camera has Mono8, Mono16"):
            camera.set_pixel_format("Mono12p")
        with pytest.raises(DeviceError, match=r"region .* does not fit"):
            camera.set_region(Region(0, 0, 4096, 16))
        with pytest.raises(DeviceError, match="outside the camera's"):
            camera.set_frame_interval(100)
        frames = list(camera.frames(150, timeout_s=2))  # 65401 + 150 crosses the 16-bit wrap
        assert camera.stream_statistics()["n_completed_buffers"] >= 150
    assert all(f.pixels.shape == (32, 64) and f.pixels.dtype == np.uint16 and f.bits == 16 for f in frames)
    seqs = [f.seq for f in frames]
    assert seqs == list(range(seqs[0], seqs[0] + 150)), "frame numbers must keep growing across the wrap"
    assert max(seqs) > 65535
    assert all(b.t_ns > a.t_ns for a, b in itertools.pairwise(frames))


@pytest.mark.timeout(30)
def test_stop_drains_the_queue_and_the_pool_stays_whole():
    require_aravis()
    with AravisCamera("Fake_1", buffers=5) as camera:
        camera.set_frame_interval(0.001)
        stream = camera.frames(timeout_s=2)
        first = next(stream)
        time.sleep(0.05)  # the camera fills the output queue while nobody reads
        inside, waiting = camera._stream.get_n_buffers()
        assert inside + waiting == 5 and waiting > 0
        stream.close()  # stops acquisition and drains the queue
        first_after = next(camera.frames(1, timeout_s=2))
    # a stale buffer from before the stop would carry one of the next few frame numbers
    assert first_after.seq > first.seq + waiting


@pytest.mark.timeout(15)
def test_missing_camera_is_a_clear_device_error():
    require_aravis()
    camera = open_camera("aravis:Aravis-Fake-NOSUCHCAMERA")
    with pytest.raises(DeviceError, match=r"cannot open: .*not found"):
        camera.open()
    assert not camera.is_open


# -- a real GigE Vision fake camera in its own process --------------------------------------

@pytest.mark.timeout(60)
def test_gige_contract_and_acquisition(gv_factory):
    fake = gv_factory()
    check_camera_contract(lambda: AravisCamera(ADDRESS))
    with open_camera(f"aravis:{fake.device_id}?buffers=6") as camera:
        assert fake.serial in camera.description
        camera.set_frame_interval(0.01)
        camera.set_region(Region(0, 0, 256, 128))
        frames = list(camera.frames(20, timeout_s=2))
        stats = camera.stream_statistics()
    assert all(f.pixels.shape == (128, 256) and f.pixels.dtype == np.uint8 for f in frames)
    assert stats["n_completed_buffers"] >= 20 and stats["n_failures"] == 0
    steps = np.diff([f.t_ns for f in frames]) / 1e9
    assert np.median(steps) == pytest.approx(0.01, rel=0.2)  # camera timestamps, 100 frames/s


@pytest.mark.timeout(60)
def test_gige_packet_loss_drops_and_counts_without_crashing(gv_factory):
    gv_factory(lost_per_thousand=20)  # 2 % of the GVSP packets never leave the camera
    with AravisCamera(ADDRESS, buffers=4) as camera:
        camera.set_frame_interval(0.005)
        camera.set_region(Region(0, 0, 128, 128))  # 12 packets a frame: some frames survive
        stream = camera.frames(timeout_s=3)
        frames = [next(stream) for _ in range(30)]
        inside, waiting = camera._stream.get_n_buffers()
        stream.close()
        stats = camera.stream_statistics()
    assert inside + waiting == 4, "every buffer, dropped ones too, goes back into the pool"
    assert len(frames) == 30
    assert camera.stats["dropped_incomplete"] > 0 and camera.stats["buffer_missing_packets"] > 0
    assert stats["n_missing_packets"] > 0 and stats["n_failures"] >= camera.stats["dropped_incomplete"]
    assert "n_resent_packets" in stats and "n_resend_requests" in stats  # reported (the fake never resends)


@pytest.mark.timeout(30)
def test_gige_nothing_but_broken_frames_times_out(gv_factory):
    gv_factory(lost_per_thousand=500)  # half the packets lost: no frame of 512x512 survives
    with AravisCamera(ADDRESS) as camera:
        started = time.monotonic()
        with pytest.raises(DeviceTimeout, match="no complete frame within 1 s, only dropped ones"):
            next(camera.frames(timeout_s=1))
        assert time.monotonic() - started < 5
    assert camera.stats["dropped_incomplete"] > 0


@pytest.mark.timeout(45)
def test_gige_camera_killed_is_device_lost(gv_factory):
    fake = gv_factory()
    with AravisCamera(ADDRESS) as camera:
        stream = camera.frames(timeout_s=1)
        next(stream)
        fake.kill()
        started = time.monotonic()
        with pytest.raises(DeviceLost):
            for _ in stream:
                pass
        assert time.monotonic() - started < 15
        assert camera.stats["lost"] == 1


@pytest.mark.timeout(90)
def test_gige_camera_killed_and_restarted_reconnects(gv_factory):
    fake = gv_factory()
    camera = AravisCamera(ADDRESS)
    waits: list[float] = []

    def backoff_sleep(seconds: float) -> None:
        waits.append(seconds)
        time.sleep(seconds)
        if len(waits) == 2:  # the first attempt found no camera; power comes back now
            fake.start(wait=False)

    camera._sleep = backoff_sleep
    with camera:
        camera.set_region(Region(0, 0, 128, 64))
        camera.set_frame_interval(0.02)
        stream = camera.frames(timeout_s=1, reconnect=Backoff(initial=0.2, factor=2, maximum=1, attempts=10))
        before = [next(stream) for _ in range(3)]
        fake.kill()
        after = [next(stream) for _ in range(5)]
        stream.close()
    assert waits[:2] == [0.2, 0.4] and len(waits) <= 3, "a failed attempt, then reconnected"
    assert camera.stats["lost"] == 1 and camera.stats["reconnects"] == 1
    assert all(f.pixels.shape == (64, 128) for f in after), "settings are applied again after reconnecting"
    steps = np.diff([f.t_ns for f in after]) / 1e9
    assert np.median(steps) == pytest.approx(0.02, rel=0.2)
    seqs = [f.seq for f in before + after]
    assert seqs == sorted(seqs) and len(set(seqs)) == len(seqs)


@pytest.mark.timeout(60)
def test_probe_command_lists_and_measures(gv_factory, capsys):
    fake = gv_factory()
    assert main(["probe", "camera", f"aravis:{ADDRESS}", "--frames", "5", "--frame-rate", "50"]) == 0
    out = capsys.readouterr().out
    assert f"aravis:{fake.device_id}" in out and f"at {ADDRESS}" in out
    assert "size: 512 x 512 pixels" in out and "format: Mono8" in out
    assert "frames/s" in out and "saturated" in out and "completed_buffers 5" in out
    assert main(["probe", "camera", "aravis:?bad=1"]) == 78
