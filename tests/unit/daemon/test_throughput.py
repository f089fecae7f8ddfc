"""Issue 13: an evaluation costs the pipeline thread one snapshot, the queue is sized by time,
the engine can follow the regions (``estimator.area = "regions"``)."""

from __future__ import annotations

import time
from collections import Counter
from pathlib import Path

import numpy as np

from edgedsm.config import AcquisitionSection, DaemonConfig
from edgedsm.daemon.capture import INITIAL_QUEUE_FRAMES, Capture, queue_capacity
from edgedsm.daemon.devices import open_camera_for
from edgedsm.daemon.pipeline import Cadence, Pipeline
from edgedsm.daemon.probes import PipelineProbes
from edgedsm.frames import Frame
from edgedsm.messages import Clock
from edgedsm.publish.sink import RecordingSink


def test_queue_capacity_by_time_bounded_by_memory() -> None:
    default = AcquisitionSection()
    assert default.queue_frames is None and default.queue_seconds == 1.0 and default.queue_max_mib == 512
    assert queue_capacity(default, None, None) == INITIAL_QUEUE_FRAMES
    assert queue_capacity(default, None, 2048 * 2048) == 128  # rate not known yet: the memory bound
    assert queue_capacity(default, 60.0, 2048 * 2048) == 60  # 1 s at 60 frames/s, 240 MiB
    assert queue_capacity(default, 150.0, 2048 * 2048) == 128  # 150 frames would be 600 MiB: 512 MiB wins
    assert queue_capacity(default, 57.0, 4096 * 2168) == 57  # Mono8 at the paper's camera: 484 MiB
    assert queue_capacity(default, 57.0, 4096 * 2168 * 2) == 30  # Mono16: 512 MiB / 17 MiB
    assert queue_capacity(default, 1.0, 64 * 64) == 2  # never fewer than 2
    assert queue_capacity(AcquisitionSection(queue_frames=7), 150.0, 2048 * 2048) == 7


class _Paced:
    paced = True



def test_the_queue_follows_the_measured_rate() -> None:
    capture = Capture(_Paced(), None, AcquisitionSection(queue_seconds=0.25), Counter())  # type: ignore[arg-type]
    assert capture.capacity == INITIAL_QUEUE_FRAMES
    pixels = np.zeros((16, 16), np.uint8)
    clock = iter(np.arange(200) / 200.0)  # 200 frames/s
    import edgedsm.daemon.capture as module

    real = module.time.monotonic
    module.time.monotonic = lambda: float(next(clock))  # type: ignore[assignment]
    try:
        for seq in range(40):
            capture.enqueue(Frame(pixels, seq=seq, t_ns=0, bits=8))
    finally:
        module.time.monotonic = real  # type: ignore[assignment]
    assert capture.capacity == 50  # 0.25 s at 200 frames/s
    # the memory bound until the rate is known (512 MiB of 256-byte frames), then 0.25 s of frames
    assert capture.counters["dropped_queue"] == 0 and capture.frames.qsize() == 40


def _replay_config(tmp_path: Path, area: str) -> DaemonConfig:
    rng = np.random.default_rng(3)
    path = tmp_path / "frames.npy"
    if not path.exists():
        np.save(path, rng.integers(0, 256, size=(60, 48, 64), dtype=np.uint8))
    return DaemonConfig.model_validate({
        "device": {"name": "t", "state_dir": str(tmp_path / f"state-{area}")},
        "camera": {"uri": f"replay:{path}?rate=0"},  # held back: no drops
        "acquisition": {"dark_frames": 0},
        "estimator": {"window": 20, "lag": 3, "area": area},
        "regions": [{"name": "a", "shape": "rect", "x": 10, "y": 5, "width": 12, "height": 8,
                     "wet_above": 0.9, "dry_below": 0.5},
                    {"name": "b", "shape": "rect", "x": 30, "y": 20, "width": 6, "height": 10,
                     "wet_above": 0.9, "dry_below": 0.5}],
    })


def _run(config: DaemonConfig) -> tuple[Pipeline, RecordingSink]:
    """A run on a clock of 10 frames/s in which each frame waits for the evaluation in flight
    (through the public probes), so both runs evaluate at the same frames."""
    sink = RecordingSink()
    box: dict[str, Pipeline] = {}

    def frame_taken(frame: Frame, count: int) -> None:
        deadline = time.monotonic() + 10
        while box["p"].evaluator.busy and time.monotonic() < deadline:
            time.sleep(0.001)

    probes = PipelineProbes(frame_taken=frame_taken)
    clock = Clock(monotonic=lambda: box["p"].counters["frames"] * 0.1 if box else 0.0,
                  wall=lambda: 1.7e9 + (box["p"].counters["frames"] * 0.1 if box else 0.0))
    pipeline = box["p"] = Pipeline(config, open_camera_for(config), sink, cadence=Cadence(1.0, 3.0), clock=clock,
                                   probes=probes)
    pipeline.run(lambda: False)
    return pipeline, sink


def test_area_regions_gives_the_same_region_statistics_on_the_box_only(tmp_path: Path) -> None:
    full_pipeline, full = _run(_replay_config(tmp_path, "frame"))
    box_pipeline, box = _run(_replay_config(tmp_path, "regions"))
    assert full_pipeline.measurement.engine is None  # released at the end
    ready_full = [s for s in full.stats if s.ready]
    ready_box = [s for s in box.stats if s.ready]
    assert len(ready_full) >= 3 and [s.frames for s in ready_full] == [s.frames for s in ready_box]
    for one, other in zip(ready_full, ready_box, strict=True):
        assert one.regions == other.regions  # bit-identical: the same sums on the box's pixels
    assert box_pipeline.measurement.crop == (slice(5, 30), slice(10, 36))
    # the maps cover the box, and say where it is
    box_maps = [m for m in box.maps if m.name == "s2"]
    full_maps = [m for m in full.maps if m.name == "s2"]
    assert box_maps and box_maps[-1].values.shape == (25, 26) and box_maps[-1].extra["origin"] == [10, 5]
    assert np.array_equal(box_maps[-1].values, full_maps[-1].values[5:30, 10:36])
    assert "origin" not in full_maps[-1].extra


def test_check_config_shows_the_queue_memory(tmp_path: Path, capsys) -> None:
    from edgedsm.cli import main

    frames = tmp_path / "frames.npy"
    np.save(frames, np.zeros((3, 2048, 2048), np.uint8))
    path = tmp_path / "c.toml"
    path.write_text(f'''[camera]
uri = "replay:{frames}"
frame_interval_s = 0.01
[[regions]]
name = "all"
wet_above = 0.9
dry_below = 0.5
''')
    assert main(["check-config", str(path)]) == 0
    out = capsys.readouterr().out
    assert "queue: 100 frames of 4.0 MiB = 400 MiB (1 s at 100 frames/s, at most 512 MiB)" in out
    path.write_text(path.read_text().replace("frame_interval_s = 0.01\n", ""))
    assert main(["check-config", str(path)]) == 0
    assert "queue: 1 s of frames at the measured rate, at most 512 MiB (128 frames of 4.0 MiB)" in (
        capsys.readouterr().out)
