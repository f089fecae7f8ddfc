"""The daemon's measurement builds its engine for the format the open camera tells, with its
pages written, before frames flow; the first frame decides (a camera that told wrong gets it
built again), later misfits are refused."""

from __future__ import annotations

import ctypes
import os
from collections import Counter

import numpy as np

from edgedsm.config import DaemonConfig
from edgedsm.daemon.measurement import Measurement
from edgedsm.daemon.pipeline import Pipeline
from edgedsm.daemon.tau import TauRegions
from edgedsm.devices.camera import SimulatedCamera
from edgedsm.estimators.snapshot import MapBuffers
from edgedsm.frames import Frame, FrameFormat
from edgedsm.publish.sink import RecordingSink
from edgedsm.sim import load_scene
from edgedsm.validation import validate
from tests.kernel_cache import REPO

SCENE = REPO / "config" / "scenes" / "drying_demo.toml"


def _config(window: int = 8) -> DaemonConfig:
    return validate(DaemonConfig, {"camera": {"uri": f"sim:{SCENE}"}, "acquisition": {"dark_frames": 0},
                                   "estimator": {"window": window, "lag": 2, "noise_floor": False}}, "<m>")


def _measurement(window: int = 8) -> Measurement:
    config = _config(window)
    return Measurement(config, TauRegions(config), MapBuffers(), Counter())


def _resident_pages(array: np.ndarray) -> tuple[int, int]:
    """(resident, all) pages of ``array``'s memory, as mincore(2) tells."""
    page = os.sysconf("SC_PAGE_SIZE")
    start = array.ctypes.data // page * page
    length = array.ctypes.data + array.nbytes - start
    pages = -(-length // page)
    vector = (ctypes.c_ubyte * pages)()
    libc = ctypes.CDLL(None, use_errno=True)
    if libc.mincore(ctypes.c_void_p(start), ctypes.c_size_t(length), vector) != 0:
        raise OSError(ctypes.get_errno(), "mincore")
    return sum(byte & 1 for byte in vector), pages


def test_the_engine_built_before_frames_flow_has_its_pages_written() -> None:
    """np.zeros pages are not resident until written; the engine's are, once prepared: the
    window's filling then faults in no fresh page at the frames' pace."""
    daemon = _measurement(window=64)
    daemon.prepare(FrameFormat.of((1024, 1024), 8), frame=False)
    assert daemon.engine is not None
    arrays = daemon.engine._arrays
    assert arrays["ring"].nbytes == 64 * 2**20
    for name, array in arrays.items():
        if array.nbytes >= 2**20:  # past malloc's heap: pages of their own
            resident, pages = _resident_pages(array)
            assert resident == pages, (name, resident, pages)


def test_the_first_frame_keeps_an_engine_built_for_its_format_and_rebuilds_a_wrong_one() -> None:
    daemon = _measurement()
    told = FrameFormat.of((32, 32), 8)
    daemon.prepare(told, frame=False)
    engine = daemon.engine
    frame = Frame(np.full((32, 32), 7, np.uint8), seq=0, t_ns=0, bits=8)
    daemon.prepare(frame.format)
    assert daemon.engine is engine and daemon.push(frame, None)

    wrong = _measurement()
    wrong.prepare(FrameFormat.of((16, 48), 8), frame=False)
    first = wrong.engine
    wrong.prepare(frame.format)  # the frame decides
    assert wrong.engine is not first and wrong.engine is not None and wrong.engine.shape == (32, 32)
    assert wrong.frame_shape == (32, 32) and wrong.push(frame, None)
    wrong.prepare(FrameFormat.of((16, 48), 8))  # settled: later frames do not rebuild it
    assert wrong.engine.shape == (32, 32)
    assert not wrong.push(Frame(np.zeros((16, 48), np.uint8), seq=1, t_ns=1, bits=8), None)
    assert wrong.counters["dropped_invalid"] == 1


class EngineWatchingCamera(SimulatedCamera):
    """Notes the daemon's engine at the moment streaming starts."""

    pipeline: Pipeline | None = None
    seen: list | None = None

    def _do_start(self) -> None:
        assert self.pipeline is not None
        engine = self.pipeline.measurement.engine
        assert self.seen is not None
        self.seen.append(None if engine is None else (engine.shape, engine.frames_seen))
        super()._do_start()


def test_the_pipeline_builds_the_engine_before_the_camera_streams() -> None:
    camera = EngineWatchingCamera(load_scene(SCENE), time_scale=0)
    camera.seen = []
    pipeline = camera.pipeline = Pipeline(_config(), camera, RecordingSink())
    pipeline.run(lambda: False, max_frames=12)
    size = load_scene(SCENE).scene.size
    assert camera.seen == [((size, size), 0)]
