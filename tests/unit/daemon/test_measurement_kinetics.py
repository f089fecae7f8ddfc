"""The daemon's measurement with [kinetics] (pipeline thread): every region's reference frames
pushed with the engine's frames, built once the frame interval is known (the configured one, else
the median step of 16 frames' timestamps), read into the snapshot, forgotten on a restart."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from edgedsm.config import DaemonConfig
from edgedsm.daemon.handover import Status
from edgedsm.daemon.measurement import KINETICS_INTERVAL_FRAMES, Measurement
from edgedsm.daemon.tau import TauRegions
from edgedsm.estimators.snapshot import MapBuffers
from edgedsm.frames import Frame
from edgedsm.validation import validate


def measurement(interval_s: float | None) -> Measurement:
    camera = {"uri": "sim:default", **({"frame_interval_s": interval_s} if interval_s else {})}
    config = validate(DaemonConfig, {"camera": camera, "estimator": {"window": 8, "lag": 1, "noise_floor": False},
                                     "kinetics": {"enabled": True, "longest_age_s": 10.0, "step": 2}}, "<k>")
    return Measurement(config, TauRegions(config), MapBuffers(), Counter())


def frames(count: int, step_ns: int):
    rng = np.random.default_rng(1)
    for seq in range(count):
        yield Frame(rng.integers(20, 200, (32, 32)).astype(np.uint8), seq=seq, t_ns=seq * step_ns, bits=8)


def status() -> Status:
    return Status(now=1.0, frames=0, fps=0.0, laser="on", drops={}, camera={}, ambient_level=None, warning=None,
                  fault=None)


def test_without_a_configured_interval_the_frames_timestamps_fix_the_longest_age() -> None:
    daemon = measurement(None)
    stream = frames(40, 50_000_000)  # 50 ms apart on the camera's clock
    for index, frame in enumerate(stream):
        daemon.prepare(frame.format)
        assert daemon.push(frame, None)
        assert daemon.kinetics is not None
        assert daemon.kinetics.built == (index + 1 >= KINETICS_INTERVAL_FRAMES), index
        if daemon.kinetics.built:
            break
    assert daemon.kinetics.longest_frames == 200  # 10 s / 0.05 s
    for frame in stream:
        daemon.push(frame, None)
    readings = daemon.snapshot(status(), False, True, 0).kinetics
    assert set(readings) == {"full"} and readings["full"].status in ("ok", "below")  # independent frames
    assert daemon.kinetics_read_s > 0 and daemon.kinetics.memory_bytes > 0
    daemon.restart()
    assert not daemon.kinetics.built and daemon.snapshot(status(), False, True, 0).kinetics["full"].status == \
        "warming_up"


def test_a_configured_interval_builds_at_the_first_frame_and_the_memory_is_budgeted() -> None:
    daemon = measurement(0.1)
    frame = next(frames(1, 1))
    daemon.prepare(frame.format)
    daemon.push(frame, None)
    assert daemon.kinetics is not None and daemon.kinetics.built and daemon.kinetics.longest_frames == 100
    slots = daemon.kinetics.section.slots(0.1)
    assert daemon.kinetics.memory_bytes == (slots + 1) * 4 * 16 * 16  # 32² at step 2
    daemon.release()
    assert daemon.kinetics is None


def test_a_region_s_kinetics_too_big_for_memory_is_refused_naming_its_key(monkeypatch: pytest.MonkeyPatch) -> None:
    from edgedsm.daemon import engine_budget
    from edgedsm.errors import ConfigError

    monkeypatch.setattr(engine_budget, "available_memory", lambda: 4 * 2**20)  # 4 MiB
    daemon = measurement(0.001)  # 10 s at 1 ms: 10,000 frames of references
    frame = Frame(np.zeros((512, 512), np.uint8), seq=0, t_ns=0, bits=8)
    with pytest.raises(ConfigError, match=r"kinetics\.longest_age_s"):
        daemon.prepare(frame.format)
