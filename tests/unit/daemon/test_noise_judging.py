"""The drying states judged on the activity above the camera's noise (estimator.noise_floor),
through the daemon's pipeline, on the simulated darkening film (config/scenes/darkening_film.toml):
its light falls to a tenth while τc rises 100×."""

from __future__ import annotations

from pathlib import Path

import pytest

from edgedsm.config import DaemonConfig
from edgedsm.devices.camera import SimulatedCamera
from edgedsm.messages import AlertKind
from edgedsm.publish.sink import RecordingSink
from edgedsm.sim import load_scene
from edgedsm.validation import validate
from tests.unit.daemon.test_pipeline import hold_back, make_pipeline

SCENE = Path(__file__).resolve().parents[3] / "config" / "scenes" / "darkening_film.toml"


def _run(noise_floor: bool) -> RecordingSink:
    data = {"camera": {"uri": f"sim:{SCENE}"}, "acquisition": {"dark_frames": 0},
            "estimator": {"window": 100, "lag": 5, "activity": "s2", "noise_floor": noise_floor},
            "regions": [{"name": "film", "wet_above": 0.30, "dry_below": 0.05, "min_dwell_s": 2.0}]}
    config = validate(DaemonConfig, data, "<darkening>")
    camera = SimulatedCamera(load_scene(SCENE), time_scale=0)
    sink = RecordingSink()
    pipeline = make_pipeline(config, camera, None, sink, dt=0.05)
    hold_back(camera, pipeline)
    pipeline.run(lambda: False, max_frames=1200)
    return sink


@pytest.fixture(scope="module")
def judged() -> RecordingSink:
    return _run(noise_floor=True)


def test_above_the_noise_the_darkening_film_goes_wet_drying_dry(judged):
    moves = [(a.from_state, a.to_state) for a in judged.alerts if a.kind == AlertKind.TRANSITION]
    assert moves == [("warming_up", "wet"), ("wet", "drying"), ("drying", "dry")]
    last = judged.stats[-1]
    signal = last.signal["film"]
    raw = last.regions["film"]["s2"].mean
    # the floor is most of what raw S2 still reads at the end; what is above it is near zero
    assert signal.noise_model == "frames" and signal.noise_floor > 0.5 * raw
    assert signal.above_noise < 0.05 and signal.above_noise == pytest.approx(raw - signal.noise_floor, abs=1e-9)
    assert judged.states[-1].regions["film"].activity == pytest.approx(signal.above_noise, abs=0.02)
    assert judged.states[-1].regions["film"].signal in ("ok", "low")


def test_the_light_falling_is_one_warning_with_its_factor(judged):
    warnings = [a for a in judged.alerts if a.kind == AlertKind.WARNING]
    assert len(warnings) == 1 and warnings[0].region == "film"
    reason = warnings[0].reason
    assert reason.startswith("mean intensity fell ") and "since the window first filled" in reason
    factor = float(warnings[0].reason.split("fell ")[1].split("×")[0])
    assert 3.0 < factor < 3.5  # the default intensity_change is 3
    assert judged.stats[-1].signal["film"].intensity_change == pytest.approx(0.1, abs=0.05)


def test_judged_on_plain_s2_the_same_film_never_reads_dry():
    sink = _run(noise_floor=False)
    moves = [(a.from_state, a.to_state) for a in sink.alerts if a.kind == AlertKind.TRANSITION]
    assert moves == [("warming_up", "wet"), ("wet", "drying")]
    assert sink.stats[-1].regions["film"]["s2"].mean > 0.05  # the noise alone keeps it above dry_below
    assert sink.stats[-1].signal == {} and sink.states[-1].regions["film"].signal is None


def test_each_state_names_its_plain_statistic_and_each_signal_the_pixels_it_was_judged_on(judged):
    stats_at = {round(stats.t, 6): stats for stats in judged.stats}
    paired = [(state, stats_at[round(state.t, 6)]) for state in judged.states
              if round(state.t, 6) in stats_at and "film" in stats_at[round(state.t, 6)].regions]
    assert len(paired) >= 5
    floored = 0
    for state, stats in paired:
        region, signal = state.regions["film"], stats.signal.get("film")
        # plain: the S2 region mean of that evaluation, from which the judged activity is taken
        assert region.plain == stats.regions["film"]["s2"].mean
        if signal is not None and signal.noise_floor is not None and region.activity is not None:
            assert region.activity == pytest.approx(region.plain - signal.noise_floor, abs=1e-12)
            assert region.activity < region.plain
            floored += 1
    assert floored >= 3
    views = {signal.view for stats in judged.stats for signal in stats.signal.values()}
    assert views == {"patch 64x64 px at the region's centre"}  # estimator.noise_patch's default
    assert "view" in judged.stats[-1].to_json()["signal"]["film"] and "plain" in judged.states[-1].to_json()[
        "regions"]["film"]
