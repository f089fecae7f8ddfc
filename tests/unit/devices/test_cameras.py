"""Simulated and replay cameras: the shared contract, laser coupling, faults, pacing."""

from __future__ import annotations

import time

import numpy as np
import pytest

from edgedsm.devices.camera import Backoff, ReplayCamera, SimulatedCamera
from edgedsm.errors import DataError, DeviceError, DeviceLost
from edgedsm.imageio import write_stack
from edgedsm.sim import scene_from_dict
from edgedsm.testing import check_camera_contract

SCENE = {"scene": {"size": 32, "frames": 10, "seed": 4, "dt": 0.01}, "activity": {"tau_c": 5.0},
         "detector": {"n_max": 1000, "bits": 8}}


def sim_scene(**extra):
    data = {**SCENE, **extra}
    return scene_from_dict(data)


@pytest.fixture
def recording(tmp_path):
    frames = np.random.default_rng(1).integers(0, 4096, size=(6, 16, 24), dtype=np.uint16)
    path = tmp_path / "rec.npy"
    np.save(path, frames)
    return path, frames


def test_simulated_camera_contract():
    check_camera_contract(lambda: SimulatedCamera(sim_scene(), time_scale=0))


@pytest.mark.parametrize("kind", ["npy", "tif", "png-folder"])
def test_replay_camera_contract(tmp_path, recording, kind):
    path, frames = recording
    if kind == "tif":
        path = write_stack(tmp_path / "rec.tif", iter(frames), len(frames))
    elif kind == "png-folder":
        path = write_stack(tmp_path / "seq" / "%03d.png", iter(frames), len(frames))
    check_camera_contract(lambda: ReplayCamera(path, bits=12))
    with ReplayCamera(path, bits=12) as camera:
        replayed = [f.pixels for f in camera.frames()]
    assert len(replayed) == 6 and all(np.array_equal(a, b) for a, b in zip(replayed, frames, strict=True))


def test_simulated_camera_follows_the_laser():
    state = {"on": False}
    scene = sim_scene(ambient_light={"eta": 0.2})
    with SimulatedCamera(scene, illuminated=lambda: state["on"], time_scale=0) as camera:
        stream = camera.frames()
        dark = [next(stream).pixels.astype(float) for _ in range(3)]
        state["on"] = True
        lit = [next(stream).pixels.astype(float) for _ in range(3)]
    ambient_grey = 200 * 255 / (1000 + np.sqrt(1000))
    for frame in dark:
        assert frame.mean() == pytest.approx(ambient_grey, rel=0.03)
        assert frame.std() < 1.5 * np.sqrt(200) * 255 / (1000 + np.sqrt(1000))
    for frame in lit:
        assert frame.std() > 3 * dark[0].std()  # speckle


def test_corrupt_buffers_are_dropped_and_counted():
    with SimulatedCamera(sim_scene(), time_scale=0, corrupt_every=3) as camera:
        frames = list(camera.frames(6))
    assert len(frames) == 6
    assert camera.stats["dropped_corrupt"] == 2  # buffers 3 and 6 of 8 grabbed
    assert [f.seq for f in frames] == [0, 1, 3, 4, 6, 7]


def test_device_loss_raises_or_reconnects():
    with SimulatedCamera(sim_scene(), time_scale=0, lose_after=3) as camera, pytest.raises(DeviceLost):
        list(camera.frames(10))
    camera = SimulatedCamera(sim_scene(), time_scale=0, lose_after=3)
    with camera:
        camera.set_exposure(500)
        delays: list[float] = []
        camera._sleep = delays.append  # no real waiting in a unit test
        frames = list(camera.frames(6, reconnect=Backoff(initial=0.1, factor=2, maximum=1)))
    assert len(frames) == 6 and camera.stats["reconnects"] == 1 and camera.stats["lost"] == 1
    assert delays == [0.1]


def test_backoff_sequence_and_giving_up():
    assert list(Backoff(initial=0.5, factor=2, maximum=3, attempts=5).delays()) == [0.5, 1, 2, 3, 3]

    class Flaky(SimulatedCamera):
        opens = 0

        def _do_open(self):
            Flaky.opens += 1
            if Flaky.opens > 1:
                raise DeviceError("cable still out")
            super()._do_open()

    with Flaky(sim_scene(), time_scale=0, lose_after=1) as camera:
        camera._sleep = lambda s: None
        with pytest.raises(DeviceLost, match="gave up reconnecting: cable still out"):
            list(camera.frames(5, reconnect=Backoff(attempts=3)))
    assert Flaky.opens == 4


def test_simulated_camera_is_paced_at_dt():
    scene = sim_scene()  # dt = 10 ms
    with SimulatedCamera(scene, time_scale=2.0) as camera:
        start = time.monotonic()
        frames = list(camera.frames(6))
        elapsed = time.monotonic() - start
    # 5 intervals of 20 ms at least (pacing never runs early); timestamps are the camera clock
    assert elapsed >= 0.095
    assert [f.t_ns for f in frames] == [i * 10_000_000 for i in range(6)]


def test_replay_rate_and_loop(recording):
    path, frames = recording
    with ReplayCamera(path, rate=200.0, loop=True) as camera:
        start = time.monotonic()
        got = list(camera.frames(9))
        elapsed = time.monotonic() - start
    assert elapsed >= 8 / 200 - 1e-3
    assert np.array_equal(got[6].pixels, frames[0]) and [f.seq for f in got] == list(range(9))


def test_replay_errors_are_clear(tmp_path):
    with pytest.raises(DeviceError, match="no such file"):
        ReplayCamera(tmp_path / "missing.npy").open()
    with pytest.raises(DeviceError, match="rate must be"):
        ReplayCamera(tmp_path, rate="fast")
    np.save(tmp_path / "f.npy", np.zeros((3, 4, 4), np.float32))
    with pytest.raises(DataError, match="uint8 or uint16"):
        ReplayCamera(tmp_path / "f.npy").open()
    np.save(tmp_path / "g.npy", np.zeros((3, 4, 4), np.uint8))
    with pytest.raises(DeviceError, match="no frame interval"):
        ReplayCamera(tmp_path / "g.npy", rate="recorded").open()


def test_replay_of_a_lossless_video_at_its_recorded_rate(tmp_path):
    import cv2

    frames = np.random.default_rng(0).integers(0, 256, size=(5, 32, 48), dtype=np.uint8)
    path = tmp_path / "rec.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 25.0, (48, 32), isColor=False)
    assert writer.isOpened()
    for frame in frames:
        writer.write(frame)
    writer.release()
    with ReplayCamera(path, rate="recorded") as camera:
        start = time.monotonic()
        got = list(camera.frames())
        elapsed = time.monotonic() - start
    assert [f.pixels.shape for f in got] == [(32, 48)] * 5
    assert all(np.array_equal(f.pixels, g) for f, g in zip(got, frames, strict=True))
    assert [f.t_ns for f in got] == [i * 40_000_000 for i in range(5)]  # 25 frames/s
    assert elapsed >= 4 * 0.04 - 1e-3
