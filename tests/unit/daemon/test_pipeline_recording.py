"""The pipeline with a recorder: alert clips around the drying plate's transitions (the ring's
frames before, the post_s after, none missing), the stats' ``recording`` section, cmd/record,
and a disk that refuses writes published as one fault alert while the states go on."""

from __future__ import annotations

from test_pipeline import hold_back, make_pipeline, setup  # noqa: F401  (the fixture)

from edgedsm.config import RecordingSection
from edgedsm.daemon.recording import FAULT_PREFIX, Recorder
from edgedsm.frameio import open_frames
from edgedsm.messages import AlertKind
from edgedsm.publish.commands import RecordCommand
from edgedsm.publish.sink import FanOut

DT = 0.05  # the pipeline's frame clock (make_pipeline): 20 frames/s


def _with_recorder(setup, tmp_path, **settings):  # noqa: F811
    config, camera, relay, publisher, _ = setup
    box = {}
    recorder = Recorder(RecordingSection.model_validate(settings), tmp_path / "rec", "demo", source="sim:",
                        monotonic=lambda: box["p"].clock.monotonic() if "p" in box else 0.0)
    pipeline = make_pipeline(config, camera, relay, FanOut([publisher, recorder]))
    pipeline.recorder = recorder
    box["p"] = pipeline
    hold_back(camera, pipeline)
    return pipeline, recorder, publisher


def test_alert_clips_hold_the_frames_before_and_after_each_transition(setup, tmp_path):  # noqa: F811
    pipeline, recorder, publisher = _with_recorder(setup, tmp_path, mode="alerts", pre_s=1.0, post_s=2.0)
    pipeline.run(lambda: False, max_frames=1300)
    recorder.close(10.0)
    transitions = [a for a in publisher.alerts if a.kind == AlertKind.TRANSITION]
    assert len(transitions) == 3
    clips = sorted(recorder.files.directory.glob("demo-*-alerts.tif"))
    assert len(clips) == 3, clips
    written = 0
    for clip in clips:
        with open_frames(clip) as reader:
            seq = reader.stamps().seq.tolist()
            laser = set(reader.stamps().laser)
            written += sum(1 for _ in reader.frames())
        assert seq == list(range(seq[0], seq[0] + len(seq)))  # consecutive: none missing
        # 1 s of ring (21 frames at most, both ends) + 2 s after the alert (40 frames)
        assert 55 <= len(seq) <= 61, (clip.name, len(seq))
        assert laser == {"on"}
    published = publisher.stats[-1].recording
    assert published is not None and published.mode == "alerts" and published.dir == str(recorder.files.directory)
    stats = recorder.stats()  # after close: every clip on disk
    assert stats.files == 3 and stats.frames_written == written
    assert stats.frames_dropped == 0 and stats.error is None


def test_cmd_record_starts_a_clip_and_without_recording_is_refused(setup, tmp_path):  # noqa: F811
    config, camera, relay, publisher, _ = setup
    bare = make_pipeline(config, camera, relay, publisher)
    refused = bare._handlers[RecordCommand](RecordCommand())
    assert not refused.ok and "[recording]" in refused.error
    pipeline, recorder, publisher = _with_recorder(setup, tmp_path, mode="timelapse", every_s=10.0)
    assert pipeline._handlers[RecordCommand](RecordCommand(seconds=1.0)).ok
    pipeline.run(lambda: False, max_frames=300)
    recorder.close(10.0)
    clip = sorted(recorder.files.directory.glob("demo-*-clip.tif"))
    lapse = sorted(recorder.files.directory.glob("demo-*-timelapse.tif"))
    assert len(clip) == 1 and len(lapse) == 1
    with open_frames(clip[0]) as reader:
        assert reader.count == 20  # 1 s at 20 frames/s
    with open_frames(lapse[0]) as reader:
        assert 1 <= reader.count <= 2  # 300 frames = 15 s, minus the clip's second


def test_a_refused_disk_is_one_fault_alert_and_the_measurement_goes_on(setup, tmp_path):  # noqa: F811
    (tmp_path / "rec").write_bytes(b"")  # a file where the folder should be
    pipeline, recorder, publisher = _with_recorder(setup, tmp_path, mode="continuous")
    pipeline.run(lambda: False, max_frames=1300)
    recorder.close(10.0)
    faults = [a for a in publisher.alerts if a.kind == AlertKind.FAULT]
    assert len(faults) == 1 and faults[0].reason.startswith(FAULT_PREFIX), faults
    moves = [(a.from_state, a.to_state) for a in publisher.alerts if a.kind == AlertKind.TRANSITION]
    assert moves == [("warming_up", "wet"), ("wet", "drying"), ("drying", "dry")]
    stats = publisher.stats[-1].recording
    assert stats.error is not None and stats.frames_written == 0 and stats.frames_dropped > 1000
