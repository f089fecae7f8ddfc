"""The pipeline in-process: simulated camera and laser, recorded publications."""

from __future__ import annotations

import time

import numpy as np
import pytest

from edgedsm.config import load_config
from edgedsm.daemon.devices import couple_simulated_laser
from edgedsm.daemon.pipeline import Cadence, Pipeline
from edgedsm.daemon.probes import PipelineProbes
from edgedsm.devices.camera import SimulatedCamera
from edgedsm.devices.laser import SimulatedRelay
from edgedsm.estimators import all_maps
from edgedsm.estimators.region_box import region_stats
from edgedsm.messages import AlertKind, Clock
from edgedsm.publish.commands import CommandResult, RebaselineCommand
from edgedsm.publish.sink import RecordingSink
from edgedsm.sim import load_scene


@pytest.fixture
def setup(repo):
    config = load_config(repo / "config" / "daemon" / "demo.toml")
    config.mqtt = None
    scene = load_scene(repo / "config" / "scenes" / "drying_demo.toml")
    scene.scene.size = 64  # same physics, 4x fewer pixels
    camera = SimulatedCamera(scene, time_scale=0)
    relay = SimulatedRelay()
    couple_simulated_laser(camera, relay)
    publisher = RecordingSink()
    return config, camera, relay, publisher, scene


def hold_back(camera, pipeline, depth=8, evaluations=True):
    """Make the simulated camera wait while the pipeline's queue holds ``depth`` frames and, with
    ``evaluations``, while an evaluation runs.

    A real camera runs at its own pace and the pipeline drops the oldest frames when it falls
    behind; these tests want every frame processed whatever the machine's load. The simulated
    camera (time_scale=0) delivers frames thousands of times faster than its Δt: an evaluation of
    tens of milliseconds (a noise floor, a τc fit) would span hundreds of simulated frames instead
    of the one or two it spans at the camera's rate, and the simulated cadence the tests judge
    would only measure the machine's load.
    """
    grab = camera._do_grab

    def waiting_grab(timeout_s):
        deadline = time.monotonic() + 10.0  # never wait forever on a stuck evaluation: the test fails on its own
        while not pipeline.capture.stopping and time.monotonic() < deadline and (
                pipeline.capture.frames.qsize() >= depth or (evaluations and pipeline.evaluator.busy)):
            time.sleep(0.001)
        return grab(timeout_s)

    camera._do_grab = waiting_grab


def make_pipeline(config, camera, relay, publisher, dt=0.05, probes=None):
    box = {}

    def frame_clock() -> float:
        return box["p"].counters["frames"] * dt if "p" in box else 0.0

    # the wall clock follows the simulated one: with the real one beside it, to_wall() would
    # depend on how far the evaluator thread lags behind, in frames
    clock = Clock(monotonic=frame_clock, wall=lambda: 1.7e9 + frame_clock())
    pipeline = Pipeline(config, camera, publisher, relay=relay, cadence=Cadence(1.0, 10.0), clock=clock, probes=probes)
    box["p"] = pipeline
    return pipeline


def test_drying_plate_goes_wet_drying_dry_and_laser_ends_off(setup):
    config, camera, relay, publisher, _ = setup
    pipeline = make_pipeline(config, camera, relay, publisher)
    hold_back(camera, pipeline)  # no drops: the run does not depend on the machine's load
    pipeline.run(lambda: False, max_frames=1300)
    assert pipeline.counters["dropped_queue"] == 0
    moves = [(a.from_state, a.to_state) for a in publisher.alerts]
    assert moves == [("warming_up", "wet"), ("wet", "drying"), ("drying", "dry")]
    times = [a.t for a in publisher.alerts]
    assert times == sorted(times)
    history = relay.board.history
    assert history[0].on is False and history[-1].on is False and not relay.board.is_on
    assert any(s.on for s in history)
    # the ambient level was measured from laser-off frames: eta = 0.05 of n_max photons
    assert pipeline.acquisition.ambient_level == pytest.approx(50 * 255 / (1000 + np.sqrt(1000)), rel=0.1)
    last = publisher.stats[-1]
    assert last.states == {"plate": "dry"} and last.ready
    assert set(last.regions["plate"]) == {"s1", "s2", "s3"}
    assert publisher.states[-1].regions["plate"].state == "dry"
    assert pipeline.summary().endswith("1300 frames, 0 dropped, laser off; plate dry")


def test_published_maps_equal_batch_maps_of_the_window(setup):
    config, camera, _relay, publisher, _ = setup
    config.estimator.ambient_correction = False
    config.acquisition.dark_frames = 0
    recorded = []
    original = camera._do_grab

    def grab(timeout_s):
        frame = original(timeout_s)
        recorded.append(frame.pixels.copy())
        return frame

    camera._do_grab = grab
    pipeline = make_pipeline(config, camera, None, publisher)
    hold_back(camera, pipeline)  # no drops: every recorded frame is pushed
    pipeline.run(lambda: False, max_frames=150)
    last = publisher.maps[-1]
    name, values = last.name, last.values
    pushed = pipeline.counters["frames"]
    # the map published at frame k is the batch map of frames k-N+1..k
    k = last.meta()["frames"]
    window = np.stack(recorded[k - config.estimator.window:k])
    expected = all_maps(window, config.estimator.lag, q=config.estimator.q)[name]
    assert pipeline.counters["dropped_queue"] == 0
    assert pushed >= k and np.allclose(values, expected, rtol=0, atol=1e-9)


def test_published_statistics_are_those_of_the_published_maps(setup):
    """The region statistics come from the live sums (region_stats), the maps from a copy: at the
    evaluation that published both, they describe the same window (issue 13)."""
    config, camera, _relay, publisher, _ = setup
    config.acquisition.dark_frames = 0
    pipeline = make_pipeline(config, camera, None, publisher)
    hold_back(camera, pipeline)
    pipeline.run(lambda: False, max_frames=150)
    assert publisher.maps and pipeline.counters["dropped_queue"] == 0
    (region,) = config.regions
    mask = region.mask(pipeline.frame_shape, config.base_dir)
    checked = 0
    for published in publisher.maps:
        frames = published.meta()["frames"]
        (stats,) = [s for s in publisher.stats if s.frames == frames]
        expected = region_stats(published.values, mask)
        got = stats.regions[region.name][published.name]
        assert got.pixels == expected.pixels
        for field in ("mean", "std", "p05", "median", "p95"):
            assert getattr(got, field) == pytest.approx(getattr(expected, field), rel=1e-12, abs=1e-15), field
        checked += 1
    assert checked >= 3  # s1, s2 and s3 of at least one evaluation


def test_camera_loss_switches_laser_off_and_faults(setup):
    config, _, relay, publisher, scene = setup
    camera = SimulatedCamera(scene, time_scale=0, lose_after=300)
    couple_simulated_laser(camera, relay)
    config.camera.reconnect_initial_s = 0.01
    pipeline = make_pipeline(config, camera, relay, publisher)
    hold_back(camera, pipeline)  # every frame before the loss measured: the window fills whatever the load
    switch_offs = []
    relay.board.add_listener(lambda on: switch_offs.append((on, pipeline.counters["frames"])))
    pipeline.run(lambda: False, max_frames=600)
    assert pipeline.counters["camera_lost"] == 1 and pipeline.counters["camera_reconnects"] == 1
    moves = [(a.from_state, a.to_state) for a in publisher.alerts if a.kind == AlertKind.TRANSITION]
    assert moves[:3] == [("warming_up", "wet"), ("wet", "fault"), ("fault", "warming_up")]
    # back to a measured state (the plate has started drying by then: wet or drying)
    assert moves[3][0] == "warming_up" and moves[3][1] in ("wet", "drying")
    # the laser went off when the camera was lost, and on again after it came back
    offs_after_start = [f for on, f in switch_offs if not on and f > 10]
    assert offs_after_start and offs_after_start[0] <= 305
    assert not relay.board.is_on


def test_queue_drops_oldest_and_counts(setup):
    config, camera, relay, publisher, _ = setup
    config.acquisition.queue_frames = 2
    camera.time_scale = 1.0  # a camera at its own pace: the queue must drop, not wait
    pipeline = make_pipeline(config, camera, relay, publisher)
    for seq in range(5):
        pipeline.capture.enqueue(seq)
    assert pipeline.counters["dropped_queue"] == 3
    assert [pipeline.capture.frames.get_nowait() for _ in range(2)] == [3, 4]


def test_bad_frames_are_dropped_and_counted(setup):
    config, camera, relay, publisher, _ = setup
    pipeline = make_pipeline(config, camera, relay, publisher)
    from edgedsm.frames import Frame

    good = Frame(np.zeros((8, 8), np.uint8), 0, 0, 8)
    pipeline._push(good)
    pipeline._push(Frame(np.zeros((9, 9), np.uint8), 1, 0, 8))
    pipeline._push(Frame(np.zeros((8, 8), np.float32), 2, 0, 8))
    pipeline._push(good)
    assert pipeline.counters["dropped_invalid"] == 2
    engine = pipeline.measurement.engine
    assert engine is not None and engine.frames_seen == 2


def test_a_window_that_cannot_fit_in_memory_is_a_config_error(monkeypatch):
    from edgedsm.daemon import engine_budget as pipeline_module
    from edgedsm.errors import ConfigError
    from edgedsm.estimators import SlidingWindow
    from edgedsm.frames import Frame

    monkeypatch.setattr(pipeline_module, "available_memory", lambda: 24 * 2**30)
    frame = Frame(np.zeros((2168, 4096), np.uint8), 0, 0, 8)

    def per_pixel(window: int, **options) -> float:
        probe = SlidingWindow((1, 8), window=window, lag=10, q=1.0, bits=8, **options)
        return pipeline_module.engine_bytes_per_pixel(probe)

    # the ring (1 byte per frame), the sums (20), their copy (20) and two sets of maps (64)
    assert per_pixel(2000) == 2000 + 20 + 20 + 64
    pipeline_module.check_engine_memory(frame.shape, per_pixel(2000))  # 17.5 GiB: fits
    with pytest.raises(ConfigError, match=r"estimator\.window: .* needs 828\.\d GiB"):
        pipeline_module.check_engine_memory(frame.shape, per_pixel(100_000))
    pipeline_module.check_engine_memory(frame.shape, per_pixel(100_000, mode="tumbling"))  # m frames only
    # τc's lag products (and their copy) count: 17 lags at max_lag 300, 4 bytes each, 8 for the edges
    with_tau = per_pixel(2000, estimators=("s1", "s2", "s3", "tau_c"), mode="tumbling", max_lag=300)
    assert with_tau > per_pixel(2000, mode="tumbling") + 2 * 17 * 4
    monkeypatch.setattr(pipeline_module, "available_memory", lambda: 8 * 2**30)
    pipeline_module.check_engine_memory(frame.shape, per_pixel(2000, mode="tumbling"))  # 1.1 GiB
    with pytest.raises(ConfigError, match=r"needs 8\.\d GiB .* max_lag"):  # the lag products: 8.8 GiB
        pipeline_module.check_engine_memory(frame.shape, with_tau)


def test_a_source_that_can_wait_is_held_back_not_dropped(repo, tmp_path):
    from edgedsm.devices.camera import ReplayCamera

    config = load_config(repo / "config" / "daemon" / "demo.toml")
    config.mqtt, config.acquisition.dark_frames, config.acquisition.queue_frames = None, 0, 2
    frames = np.random.default_rng(0).integers(0, 256, size=(300, 16, 16), dtype=np.uint8)
    np.save(tmp_path / "rec.npy", frames)
    camera = ReplayCamera(tmp_path / "rec.npy", rate=0)
    assert not camera.paced
    pipeline = Pipeline(config, camera, RecordingSink())
    pipeline.run(lambda: False)
    assert pipeline.counters["frames"] == 300 and pipeline.counters["dropped_queue"] == 0


def test_bursts_spare_the_laser(setup):
    config, camera, relay, publisher, _ = setup
    config.acquisition.mode = "bursts"
    config.acquisition.burst_frames = 120
    config.acquisition.burst_period_s = 20.0  # 400 frames of 0.05 s: laser on for 120 of them
    config.acquisition.dark_frames = 0
    pipeline = make_pipeline(config, camera, relay, publisher)
    hold_back(camera, pipeline)
    switched = []
    relay.board.add_listener(lambda on: switched.append((on, pipeline.counters["frames"])))
    pipeline.run(lambda: False, max_frames=1000)
    ons = [frame for on, frame in switched if on]
    offs = [frame for on, frame in switched if not on and frame > 0]
    # bursts start every 400 frames (0, 400, 800) and end 120 pushed frames later
    assert len(ons) == 3 and ons[1] - ons[0] == pytest.approx(400, abs=3)
    assert all(90 <= off - on <= 130 for on, off in zip(ons, offs, strict=False))
    assert not relay.board.is_on
    # each burst's window filled: states were judged (warming_up only before the first)
    assert publisher.alerts and publisher.alerts[0].from_state == "warming_up"


def test_published_times_are_wall_clock(setup):
    """`since` was the monotonic clock on the wire (seen as 3173.74): now UTC epoch seconds."""
    config, camera, relay, publisher, _ = setup
    config.acquisition.dark_frames = 0
    pipeline = Pipeline(config, camera, publisher, relay=relay, cadence=Cadence(0.05, 10.0))
    hold_back(camera, pipeline)
    pipeline.run(lambda: False, max_frames=300)
    now = time.time()
    assert publisher.states and publisher.stats and publisher.alerts
    for report in publisher.states:
        assert abs(report.t - now) < 60
        assert all(abs(region.since - now) < 60 for region in report.regions.values())
    assert all(abs(stats.t - now) < 60 for stats in publisher.stats)
    assert all(abs(alert.t - now) < 60 for alert in publisher.alerts)
    # `since` of the last report is when the region entered its state: at or before the report
    last = publisher.states[-1]
    assert last.regions["plate"].since <= last.t + 1e-6


def test_a_sink_is_added_without_touching_the_pipeline(setup):
    """Two recording sinks behind a FanOut see the same messages from one real run."""
    from edgedsm.publish.sink import FanOut

    config, camera, relay, _, _ = setup
    first, second = RecordingSink(), RecordingSink()
    pipeline = make_pipeline(config, camera, relay, FanOut([first, second]))
    hold_back(camera, pipeline)
    pipeline.run(lambda: False, max_frames=700)
    assert len(first.stats) >= 30 and [s.frames for s in first.stats] == [s.frames for s in second.stats]
    assert [(a.from_state, a.to_state) for a in first.alerts] == [("warming_up", "wet"), ("wet", "drying")]
    assert first.alerts == second.alerts and first.states == second.states
    assert [m.name for m in first.maps] == [m.name for m in second.maps] and len(first.maps) >= 3
    assert all(a.values is b.values for a, b in zip(first.maps, second.maps, strict=True))


def test_probes_see_every_frame_and_every_evaluation(setup):
    config, camera, relay, publisher, _ = setup
    seen: dict[str, list] = {"queued": [], "taken": [], "pushed": [], "snapshots": [], "evaluated": [], "states": []}
    probes = PipelineProbes(frame_queued=lambda frame, t: seen["queued"].append(frame.seq),
                            frame_taken=lambda frame, count: seen["taken"].append(count),
                            frame_pushed=lambda frame, t, cost: seen["pushed"].append(cost),
                            snapshot_taken=lambda snapshot, cost: seen["snapshots"].append(snapshot),
                            evaluated=lambda stats, seconds: seen["evaluated"].append(stats.frames),
                            states_evaluated=lambda frames, t: seen["states"].append(frames))
    pipeline = make_pipeline(config, camera, relay, publisher, probes=probes)
    hold_back(camera, pipeline)
    pipeline.run(lambda: False, max_frames=400)
    dark = config.acquisition.dark_frames + 1
    assert seen["taken"] == list(range(1, 401))
    # the first frame after switching on is left out (exposed while the relay switched)
    assert len(seen["pushed"]) == 400 - dark - 1 and all(cost >= 0 for cost in seen["pushed"])
    assert len(seen["queued"]) >= 400
    assert seen["evaluated"] == [s.frames for s in publisher.stats]
    with_stats = [snapshot for snapshot in seen["snapshots"] if snapshot.publish_stats]
    assert len(with_stats) == len(publisher.stats) >= 15 and with_stats[-1].ready
    # the drying states are judged every 0.5 s (10 frames here) whatever the stats cadence (1 s)
    assert seen["states"] == [snapshot.status.frames for snapshot in seen["snapshots"]]
    assert len(seen["snapshots"]) >= 2 * len(publisher.stats) - 1


def test_cadence_is_kept_on_a_grid_not_counted_from_each_late_evaluation() -> None:
    from edgedsm.daemon.pipeline import next_due

    assert next_due(float("-inf"), 0.5, 3.0) == 3.5  # the first: from now
    assert next_due(3.5, 0.5, 3.54) == 4.0  # noticed a frame late: the grid keeps its rate
    assert next_due(4.0, 0.5, 4.9) == 5.4  # more than a period late: from now, no burst


def test_drying_states_are_judged_twice_a_second_at_a_frame_rate_that_does_not_divide_it(setup):
    # 33 frames/s: the loop notices a due cadence up to 30 ms late; counted from each evaluation,
    # the states would be judged every 0.51 s and the stats every 1.02 s
    config, camera, relay, publisher, _ = setup
    times: list[float] = []
    probes = PipelineProbes(snapshot_taken=lambda snapshot, cost: times.append(snapshot.status.now))
    pipeline = make_pipeline(config, camera, relay, publisher, dt=0.03, probes=probes)
    hold_back(camera, pipeline)
    pipeline.run(lambda: False, max_frames=600)
    gaps = np.diff(times[2:])  # after the laser went on (urgent evaluations)
    assert len(gaps) >= 30 and float(np.mean(gaps)) <= 0.503, gaps
    stats = np.diff([stats.t for stats in publisher.stats][2:])
    assert len(stats) >= 14 and float(np.mean(stats)) <= 1.003, stats


def test_rebaseline_publishes_one_reset_alert_and_the_states_start_again(setup):
    # as a reload does (docs/mqtt.md: "reset: measurement restarted"), not one X -> warming_up
    # transition per region
    import threading

    config, camera, relay, publisher, _ = setup
    pipeline = make_pipeline(config, camera, relay, publisher)
    hold_back(camera, pipeline)
    replies: list[object] = []

    def stop() -> bool:
        if pipeline.counters["frames"] >= 450 and not replies:
            replies.append(None)
            threading.Thread(target=lambda: replies.append(pipeline.submit(RebaselineCommand()))).start()
        return False

    pipeline.run(stop, max_frames=900)
    assert replies[-1] == CommandResult()
    kinds = [(a.kind, a.from_state, a.to_state) for a in publisher.alerts]
    assert kinds[0] == (AlertKind.TRANSITION, "warming_up", "wet"), kinds
    reset = [a for a in publisher.alerts if a.kind == AlertKind.RESET]
    assert len(reset) == 1 and reset[0].region is None and "rebaseline" in reset[0].reason, publisher.alerts
    after = publisher.alerts[publisher.alerts.index(reset[0]) + 1:]
    assert all(a.to_state != "warming_up" for a in publisher.alerts if a.kind == AlertKind.TRANSITION)
    assert after and after[0].from_state == "warming_up"  # the states start again from warming up
    later = [s for s in publisher.states if s.t >= reset[0].t]
    assert later and later[0].regions["plate"].state == "warming_up"


class PacedSimulatedCamera(SimulatedCamera):
    """The simulator as fast as it runs, but a camera that cannot wait (a real one's contract)."""

    paced = True  # type: ignore[assignment]


@pytest.mark.parametrize(("paced", "depth", "stats_every_s"), [(True, 7, 4.0), (True, 2, 1.0), (False, 7, 1.0)])
def test_statistics_wait_while_a_paced_cameras_queue_is_half_full_and_the_states_go_on(setup, paced, depth,
                                                                                        stats_every_s):
    # frames come first: with a paced camera's queue at 7 of 8 the statistics (region pass,
    # percentiles, maps) wait, at most POSTPONE_MAX_INTERVALS = 4 intervals, and the drying states
    # are judged twice a second meanwhile; a queue at 2 of 8, or a source that can wait, changes nothing
    config, _camera, relay, publisher, scene = setup
    config.acquisition.queue_frames = 8
    camera = (PacedSimulatedCamera if paced else SimulatedCamera)(scene, time_scale=0)
    couple_simulated_laser(camera, relay)
    judged: list[int] = []
    probes = PipelineProbes(frame_taken=lambda frame, count: time.sleep(0.004),  # slower than the camera
                            states_evaluated=lambda frames, t: judged.append(frames))
    pipeline = make_pipeline(config, camera, relay, publisher, dt=0.05, probes=probes)
    hold_back(camera, pipeline, depth=depth)  # the queue stays that full, nothing dropped
    pipeline.run(lambda: False, max_frames=700)
    assert pipeline.counters["dropped_queue"] == 0
    assert (pipeline.counters["stats_postponed"] > 0) == (stats_every_s > 1.0)
    gaps = np.diff([stats.t for stats in publisher.stats][2:])  # after the laser went on
    assert len(gaps) >= 28 / stats_every_s - 2 and np.median(gaps) == pytest.approx(stats_every_s, abs=0.06), gaps
    states = np.diff(judged[2:])  # frames between two judgements: 0.5 s is 10 frames
    assert len(states) >= 40 and np.median(states) == 10, states


def test_without_a_cadence_the_pipeline_takes_the_configurations(setup):
    """The intervals' defaults live in the configuration alone: a pipeline built without a
    cadence evaluates on ``[cadence]``, as the service's does."""
    from edgedsm.config import CadenceSection

    config, camera, _, publisher, _ = setup
    config.cadence = defaults = CadenceSection()  # demo.toml sets its own
    assert Pipeline(config, camera, publisher).cadence == Cadence(defaults.stats_interval_s, defaults.maps_interval_s)
    config.cadence = CadenceSection(stats_interval_s=7.0, maps_interval_s=70.0)
    cadence = Pipeline(config, camera, publisher).cadence
    assert (cadence.stats_every_s, cadence.maps_every_s) == (7.0, 70.0)
