"""Each region's kinetics in seconds (edgedsm.measurement.kinetics) and in the measurement core's
readings: τ·Δt and its rate, the statuses of a dark region, subsampling, warming up, the judged
value (issue 37)."""

from __future__ import annotations

import numpy as np
import pytest

from edgedsm.config import DaemonConfig
from edgedsm.config.kinetics import KineticsSection
from edgedsm.errors import EstimatorError
from edgedsm.estimators.kinetics import ABOVE, DARK, OK, WARMING_UP
from edgedsm.estimators.noise import NoiseModel
from edgedsm.measurement import Core
from edgedsm.measurement.kinetics import KineticsRegions, judged_seconds
from edgedsm.messages import RegionKinetics
from edgedsm.sim import Simulator, scene_from_dict
from edgedsm.sim.detector import DetectorRows
from edgedsm.validation import validate

SIZE, TAU_FRAMES, DT = 32, 6.0, 0.05


def film(frames: int, seed: int = 3) -> tuple[list[np.ndarray], NoiseModel]:
    scene = scene_from_dict({"scene": {"size": SIZE, "seed": seed}, "activity": {"tau_c": TAU_FRAMES},
                             "detector": {"n_max": 1000.0, "bits": 8}})
    simulator = Simulator(scene)
    return [simulator.next_frame() for _ in range(frames)], NoiseModel(gain=DetectorRows(scene).scale)


def halves() -> dict[str, np.ndarray]:
    left = np.zeros((SIZE, SIZE), bool)
    left[:, : SIZE // 2] = True
    return {"lit": left, "dark": ~left}


def test_tau_in_seconds_its_rate_and_a_dark_region_as_a_status() -> None:
    frames, model = film(400)
    regions = KineticsRegions(KineticsSection(enabled=True, longest_age_s=10.0), halves(), model)
    assert all(r.status == WARMING_UP and r.tau_s is None for r in regions.read(DT).values())
    regions.push(frames[0], None)  # no interval yet: not counted
    assert regions.pushed == 0 and not regions.regions
    taus = []
    for index, frame in enumerate(frames):
        dark = frame.copy()
        dark[:, SIZE // 2:] = 0  # the right half unlit
        regions.push(dark, DT)
        if index >= 50 and index % 10 == 0:
            out = regions.read(DT)
            lit, unlit = out["lit"], out["dark"]
            assert unlit.status == DARK and unlit.tau_s is None and unlit.rate_hz is None
            assert lit.status == OK and lit.rate_hz == pytest.approx(1.0 / lit.tau_s) and lit.frame == index
            taus.append(lit.tau_s)
    assert regions.longest_frames == 200 and regions.memory_bytes > 0
    # the simulator's random-walk phase: g = exp(-t/τc), τ = τc frames (docs/kinetics.md)
    assert np.median(taus) == pytest.approx(TAU_FRAMES * DT, rel=0.15)
    regions.reset()
    assert regions.read(DT)["lit"].status == WARMING_UP


def test_subsampled_regions_keep_the_measure_and_a_sixteenth_of_the_memory() -> None:
    frames, model = film(300, seed=5)
    full = KineticsRegions(KineticsSection(enabled=True, longest_age_s=5.0), {"all": np.ones((SIZE, SIZE), bool)},
                           model)
    sub = KineticsRegions(KineticsSection(enabled=True, longest_age_s=5.0, step=4),
                          {"all": np.ones((SIZE, SIZE), bool)}, model)
    full_taus, sub_taus = [], []
    for index, frame in enumerate(frames):
        full.push(frame, DT)
        sub.push(frame, DT)
        if index >= 50 and index % 10 == 0:
            full_taus.append(full.read(DT)["all"].tau_s)
            sub_taus.append(sub.read(DT)["all"].tau_s)
    assert sub.memory_bytes * 16 == full.memory_bytes
    assert KineticsRegions.bytes_for(sub.section, sub.masks, DT) > 0
    assert np.median(sub_taus) == pytest.approx(np.median(full_taus), rel=0.2)
    with pytest.raises(EstimatorError, match="keeps no pixel"):
        mask = np.zeros((SIZE, SIZE), bool)
        mask[1, 1] = True
        KineticsRegions(KineticsSection(step=4), {"dot": mask})


def test_the_automatic_step_subsamples_the_frames_as_it_does_the_masks(monkeypatch: pytest.MonkeyPatch) -> None:
    """step = None (the default): the step chosen for the regions is the frames' too (a frame pushed
    whole beside masks subsampled would not match their shape)."""
    from edgedsm.config import kinetics as kinetics_config

    monkeypatch.setattr(kinetics_config, "AUTO_PIXELS", 64)  # a 32² region: step 4 (at most 64 pixels)
    frames, model = film(300, seed=5)
    auto = KineticsRegions(KineticsSection(enabled=True, longest_age_s=5.0), {"all": np.ones((SIZE, SIZE), bool)},
                           model)
    given = KineticsRegions(KineticsSection(enabled=True, longest_age_s=5.0, step=4),
                            {"all": np.ones((SIZE, SIZE), bool)}, model)
    assert auto.step == 4 and auto.masks["all"].shape == (SIZE // 4, SIZE // 4)
    for frame in frames:
        auto.push(frame, DT)
        given.push(frame, DT)
    assert auto.read(DT) == given.read(DT) and auto.read(DT)["all"].status == OK


def test_the_judged_value_is_tau_or_its_bound_never_a_dark_number() -> None:
    assert judged_seconds(RegionKinetics(status=OK, tau_s=2.0, rate_hz=0.5)) == 2.0
    assert judged_seconds(RegionKinetics(status=ABOVE, bound_s=400.0)) == 400.0
    assert judged_seconds(RegionKinetics(status=DARK)) is None
    assert judged_seconds(None) is None


def test_the_core_reads_kinetics_and_judges_on_it() -> None:
    frames, model = film(300, seed=7)
    config = validate(DaemonConfig, {
        "camera": {"uri": "sim:default", "noise": {"gain": model.gain}},
        "estimator": {"activity": "kinetics", "window": 20, "lag": 2},
        "kinetics": {"enabled": True, "longest_age_s": 20.0},
        "regions": [{"name": "plate", "wet_below_s": 1.0, "dry_above_s": 10.0, "min_dwell_s": 0.0}]}, "<k>")
    core = Core(config, {"plate": np.ones((SIZE, SIZE), bool)}, dt=DT)
    readings = []
    for index, frame in enumerate(frames):
        core.push(frame, 8)
        if core.ready and index % 25 == 0:
            readings.append(core.read(index * DT).readings["plate"])
    reading = readings[-1]
    assert reading.estimator == "kinetics" and reading.kinetics is not None and reading.kinetics.status == OK
    assert reading.plain == reading.kinetics.tau_s == pytest.approx(TAU_FRAMES * DT, rel=0.25)
    assert reading.activity == reading.plain  # judged as τc is: the value itself
    assert reading.state == "wet"  # 0.3 s, below wet_below_s = 1 s
    assert core.kinetics is not None and core.kinetics.noise.gain == model.gain  # the datasheet's model
