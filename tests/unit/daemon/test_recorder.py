"""The daemon's recorder: which frames each mode keeps (fake clock), clips around alerts from the
ring, time-lapse, segments, the bounded queue dropping and counting, retention by size and age,
and a disk that refuses writes (a fault once, recovery) — files read back with edgedsm.frameio."""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import pytest

from edgedsm.config import RecordingSection
from edgedsm.daemon.recording import FAULT_PREFIX, Recorder
from edgedsm.daemon.recording_files import FrameQueue, name_pattern, utc_stamp
from edgedsm.frameio import open_frames
from edgedsm.frames import Frame
from edgedsm.messages import Alert, AlertKind

SHAPE = (32, 48)
WALL0 = 1_780_000_000.0


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def monotonic(self) -> float:
        return self.t

    def wall(self) -> float:
        return WALL0 + self.t


def _frame(seq: int, shape: tuple[int, int] = SHAPE) -> Frame:
    pixels = np.random.default_rng(seq).integers(0, 256, shape, dtype=np.uint8)
    return Frame(pixels, seq, seq * 40_000_000, 8)


def _recorder(tmp_path: Path, clock: FakeClock, start: bool = True, **settings: object) -> Recorder:
    section = RecordingSection.model_validate(settings)
    return Recorder(section, tmp_path / "rec", "cam1", source="sim:default", monotonic=clock.monotonic,
                    wall=clock.wall, start=start)


def _feed(recorder: Recorder, clock: FakeClock, first: int, count: int, dt: float = 0.125,
          laser: str = "on") -> None:
    for seq in range(first, first + count):
        recorder.offer(_frame(seq), laser)
        clock.t += dt


def _queued(recorder: Recorder) -> list[tuple[int, str, int | None]]:
    items = []
    while (item := recorder.queue.get(0)) is not None:
        items.append((item[0], item[1], item[2].seq if item[2] is not None else None))
    return items


def _files(recorder: Recorder) -> list[Path]:
    return sorted(recorder.files.directory.glob("*.tif"))


def _seqs(path: Path) -> list[int]:
    with open_frames(path) as reader:
        return reader.stamps().seq.tolist()


def test_continuous_keeps_every_frame_and_cuts_a_file_every_segment_s(tmp_path):
    clock = FakeClock()
    recorder = _recorder(tmp_path, clock, start=False, mode="continuous", segment_s=2.0)
    _feed(recorder, clock, 0, 50)  # 6.25 s at 8 frames/s (the fake clock's steps are exact)
    items = _queued(recorder)
    assert [seq for _, _, seq in items] == list(range(50))
    segments = [segment for segment, _, _ in items]
    assert [segments.count(s) for s in sorted(set(segments))] == [16, 16, 16, 2]  # 0-2, 2-4, 4-6, 6- s
    assert {label for _, label, _ in items} == {"continuous"}


def test_timelapse_keeps_one_frame_every_every_s(tmp_path):
    clock = FakeClock()
    recorder = _recorder(tmp_path, clock, start=False, mode="timelapse", every_s=1.0)
    _feed(recorder, clock, 0, 44)  # 0.0 ... 5.375 s
    assert [seq for _, _, seq in _queued(recorder)] == [0, 8, 16, 24, 32, 40]


def test_alerts_mode_queues_nothing_until_an_alert_then_pre_and_post_frames_in_one_clip(tmp_path):
    clock = FakeClock()
    recorder = _recorder(tmp_path, clock, start=False, mode="alerts", pre_s=1.0, post_s=2.0)
    _feed(recorder, clock, 0, 100)
    assert _queued(recorder) == []
    assert len(recorder._ring) == 9  # frames of the last pre_s (1.0 s at 0.125 s, both ends)
    recorder.publish_alert(Alert(kind=AlertKind.TRANSITION, t=0.0, region="a", from_state="wet", to_state="drying"))
    _feed(recorder, clock, 100, 40)
    items = _queued(recorder)
    frames = [seq for _, _, seq in items if seq is not None]
    assert frames == list(range(91, 116))  # 9 from the ring, then 2 s after the alert (16 frames)
    assert items[-1][2] is None  # the clip's file is closed at its end
    assert len({segment for segment, _, _ in items}) == 1 and {label for _, label, _ in items} == {"alerts"}
    assert not recorder.stats().clip_active


def test_a_second_alert_during_a_clip_extends_it_and_own_faults_start_none(tmp_path):
    clock = FakeClock()
    recorder = _recorder(tmp_path, clock, start=False, mode="alerts", pre_s=0.0, post_s=1.0)
    recorder.publish_alert(Alert(kind=AlertKind.FAULT, t=0.0, reason="camera lost"))
    _feed(recorder, clock, 0, 5)
    recorder.publish_alert(Alert(kind=AlertKind.FAULT, t=0.0, reason="camera lost again"))
    _feed(recorder, clock, 5, 20)
    frames = [seq for _, _, seq in _queued(recorder) if seq is not None]
    assert frames == list(range(0, 13))  # one clip, to 0.625 + 1.0 s
    for alert in (Alert(kind=AlertKind.FAULT, t=0.0, reason=FAULT_PREFIX + "disk full"),
                  Alert(kind=AlertKind.WARNING, t=0.0, reason="ambient"), Alert(kind=AlertKind.RESET, t=0.0)):
        recorder.publish_alert(alert)
    _feed(recorder, clock, 25, 10)
    assert _queued(recorder) == []


def test_the_ring_is_bounded_by_its_memory(tmp_path):
    clock = FakeClock()
    recorder = _recorder(tmp_path, clock, start=False, mode="alerts", pre_s=600.0, ring_max_mib=1)
    big = (512, 512)  # 256 KiB a frame: 4 fit in 1 MiB
    for seq in range(20):
        recorder.offer(_frame(seq, big), "on")
        clock.t += 0.1
    assert len(recorder._ring) == 4 and recorder._ring_bytes <= 2**20


def test_cmd_record_clip_in_continuous_mode_is_a_file_of_its_own(tmp_path):
    clock = FakeClock()
    recorder = _recorder(tmp_path, clock, start=False, mode="continuous", segment_s=600.0)
    _feed(recorder, clock, 0, 10)
    assert recorder.request_clip(0.5) == 0.5
    _feed(recorder, clock, 10, 20)
    items = _queued(recorder)
    labels = [(label, seq) for _, label, seq in items]
    assert [seq for label, seq in labels if label == "clip" and seq is not None] == list(range(10, 14))
    assert [seq for label, seq in labels if label == "continuous"] == list(range(10)) + list(range(14, 30))
    segments = [segment for segment, label, seq in items if label == "continuous"]
    assert segments[0] != segments[-1]  # continuous resumes in a new file after the clip


def test_a_full_queue_drops_and_counts_never_waits(tmp_path):
    clock = FakeClock()
    recorder = _recorder(tmp_path, clock, start=False, mode="continuous", queue_max_mib=1)
    big = (512, 512)
    started = time.perf_counter()
    for seq in range(12):
        recorder.offer(_frame(seq, big), "on")
    assert time.perf_counter() - started < 5.0
    assert len(recorder.queue) == 4 and recorder.dropped == 8
    assert recorder.stats().frames_dropped == 8


def test_frame_queue_takes_one_frame_larger_than_its_bound():
    queue = FrameQueue(10)
    assert queue.put((1, "continuous", _frame(0), "on", 0.0))
    assert not queue.put((1, "continuous", _frame(1), "on", 0.0))
    assert queue.get(0)[2].seq == 0 and queue.get(0.01) is None


def test_files_are_written_readable_and_named(tmp_path):
    clock = FakeClock()
    recorder = _recorder(tmp_path, clock, mode="continuous", segment_s=1.0)
    _feed(recorder, clock, 0, 20, laser="off")
    recorder.close(10.0)
    files = _files(recorder)
    assert len(files) == 3
    assert all(name_pattern("cam1").match(path.name) for path in files), files
    assert files[0].name == f"cam1-{utc_stamp(WALL0 + 100.0)}-continuous.tif"
    assert [_seqs(path) for path in files] == [list(range(8)), list(range(8, 16)), list(range(16, 20))]
    with open_frames(files[1]) as reader:
        assert np.array_equal(next(iter(reader.frames())), _frame(8).pixels)
        assert reader.stamps().laser[0] == "off" and reader.header["mode"] == "continuous"
    stats = recorder.stats()
    assert (stats.files, stats.frames_written, stats.frames_dropped) == (3, 20, 0)
    assert stats.bytes == sum(path.stat().st_size for path in files)


def test_retention_keeps_the_total_within_max_bytes_deleting_the_oldest(tmp_path):
    clock = FakeClock()
    foreign = tmp_path / "rec" / "notes.tif"
    foreign.parent.mkdir()
    foreign.write_bytes(b"x" * 100)  # not a name this device writes: never deleted
    recorder = _recorder(tmp_path, clock, mode="continuous", segment_s=1.0, max_bytes=4 * 2**20)
    frame_bytes = 300_000
    most = 0
    for seq in range(80):  # 80 x 300 kB noise = 24 MB through a 4 MiB budget
        pixels = np.random.default_rng(seq).integers(0, 256, frame_bytes, dtype=np.uint8).reshape(500, 600)
        recorder.offer(Frame(pixels, seq, seq, 8), "on")
        clock.t += 0.25
        assert recorder.queue.wait_empty(10) and recorder.files.wait_idle(10)
        most = max(most, sum(p.stat().st_size for p in _files(recorder) if p != foreign))
    recorder.close(10.0)
    kept = [path for path in _files(recorder) if path != foreign]
    total = sum(path.stat().st_size for path in kept)
    assert most <= 4 * 2**20 and total <= 4 * 2**20
    assert recorder.files.deleted >= 4 and foreign.exists()
    last = [seq for path in kept for seq in _seqs(path)]
    assert last == list(range(80 - len(last), 80))  # the newest frames, in order, none missing


def test_keep_days_deletes_files_older_at_start(tmp_path):
    directory = tmp_path / "rec"
    directory.mkdir()
    old, new = directory / "cam1-20200101T000000.000Z-alerts.tif", directory / "cam1-20260101T000000.000Z-alerts.tif"
    for path in (old, new):
        path.write_bytes(b"II")
    os.utime(old, (WALL0 - 3 * 86_400, WALL0 - 3 * 86_400))
    os.utime(new, (WALL0, WALL0))
    clock = FakeClock()
    recorder = _recorder(tmp_path, clock, mode="alerts", keep_days=2.0)
    recorder.close(5.0)
    assert not old.exists() and new.exists()
    assert recorder.stats().files == 1


def test_a_refused_write_is_one_fault_frames_dropped_then_recovered(tmp_path):
    clock = FakeClock()
    blocker = tmp_path / "rec"
    blocker.write_bytes(b"")  # a file where the folder should be: every write is refused
    recorder = _recorder(tmp_path, clock, mode="continuous")
    _feed(recorder, clock, 0, 5)
    assert recorder.queue.wait_empty(10) and recorder.files.wait_idle(10)
    faults = recorder.pending_faults()
    assert len(faults) == 1 and faults[0].startswith(FAULT_PREFIX) and str(blocker) in faults[0], faults
    assert recorder.stats().error is not None and recorder.stats().frames_dropped == 5
    blocker.unlink()
    clock.t += 60.0  # past the backoff
    _feed(recorder, clock, 5, 3)
    recorder.close(10.0)
    assert recorder.pending_faults() == []
    assert recorder.stats().error is None and recorder.stats().frames_written == 3
    assert [_seqs(path) for path in _files(recorder)] == [[5, 6, 7]]


def test_offers_after_close_are_ignored(tmp_path):
    clock = FakeClock()
    recorder = _recorder(tmp_path, clock, mode="continuous")
    recorder.close(1.0)
    recorder.offer(_frame(0), "on")
    assert len(recorder.queue) == 0


@pytest.mark.parametrize("bad", [{"codec": "jpeg"}, {"mode": "sometimes"}, {"max_bytes": 1000}, {"pre_s": -1},
                                 {"speed": 1}])
def test_bad_settings_are_refused(bad):
    with pytest.raises(ValueError):
        RecordingSection.model_validate(bad)
