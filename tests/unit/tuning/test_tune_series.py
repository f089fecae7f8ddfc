"""One pass of ``edgedsm tune`` (edgedsm.tuning.series) with the field's descriptors as the daemon
judges them: Fujii is 200·S2 at q = 0 (its own engine at q = 0 when the config's q is not), its
above-noise value in the same units, and a snippet choosing it is a daemon config; GD, when asked
for, is the region mean of each window's GD, in the window modes only."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from edgedsm.config import DaemonConfig
from edgedsm.estimators import descriptors
from edgedsm.sim import Simulator, load_scene
from edgedsm.tuning.candidates import Candidate, candidates, evaluate
from edgedsm.tuning.output import snippet
from edgedsm.tuning.series import Setting, run_pass
from edgedsm.tuning.session import Result, Run
from edgedsm.validation import validate

REPO = Path(__file__).resolve().parents[3]
#: the demo plate at 32², drying (τc ×100) between 5 s and 15 s
SCENE = (REPO / "config" / "scenes" / "drying_demo.toml").read_text().replace("size = 128", "size = 32").replace(
    "start = 200\nduration = 800", "start = 100\nduration = 200")
FRAMES, DT, WET_UNTIL, DRY_FROM = 500, 0.05, 5.0, 15.0
SETTING = Setting(50, 5)
REGION = {"name": "plate", "shape": "rect", "x": 4, "y": 4, "width": 24, "height": 24, "wet_above": 0.3,
          "dry_below": 0.1, "min_dwell_s": 2}


def _config(scene: Path, **estimator: object) -> DaemonConfig:
    data = {"camera": {"uri": f"sim:{scene}"}, "estimator": {"window": 100, "lag": 5, **estimator},
            "regions": [REGION]}
    return validate(DaemonConfig, data, "<test>")


@pytest.fixture(scope="module")
def plate(tmp_path_factory) -> tuple[Path, np.ndarray, dict[str, np.ndarray]]:
    folder = tmp_path_factory.mktemp("series")
    (folder / "scene.toml").write_text(SCENE)
    frames = np.stack(list(Simulator(load_scene(folder / "scene.toml")).frames(FRAMES)))
    config = _config(folder / "scene.toml")
    masks = {r.name: r.mask(frames.shape[1:], config.base_dir) for r in config.regions}
    return folder / "scene.toml", frames, masks


@pytest.fixture(scope="module")
def passes(plate):
    """The same pass at q = 0 (one engine) and at the default q = 1 (Fujii from its own engine)."""
    scene, frames, masks = plate
    wanted = ("s2", "fujii", "im", "contrast")
    return {q: run_pass(iter(frames), SETTING, _config(scene, q=q), masks, DT, step=10, bits=8, estimators=wanted)
            for q in (0.0, 1.0)}


def test_fujii_is_200_times_s2_at_q_0_and_its_own_engine_gives_it_when_q_is_not_0(passes):
    at_0, at_1 = passes[0.0], passes[1.0]
    assert len(at_0.times) == len(at_1.times) == (FRAMES - SETTING.window) // 10 + 1
    s2_0, fujii_0 = at_0.array("plate", "s2"), at_0.array("plate", "fujii")
    assert s2_0.max() > 3.0 * s2_0.min() > 0.1  # an activity that moves (about 0.31 wet, 0.07 dry)
    np.testing.assert_allclose(fujii_0, 200.0 * s2_0, rtol=1e-12)
    np.testing.assert_allclose(at_1.array("plate", "fujii"), fujii_0, rtol=1e-12)  # q = 0 whatever the config's
    s2_1 = at_1.array("plate", "s2")
    assert np.all(s2_1 < s2_0) and np.all(s2_1 > 0.9 * s2_0)  # S2 at q = 1 is judged at the config's q
    # above the noise: the daemon's judge on Fujii's floor, in Fujii's units (200 × S2's floor at q = 0)
    above_fujii, above_s2 = at_0.array("plate", "fujii@noise"), at_0.array("plate", "s2@noise")
    judged = np.isfinite(above_fujii)
    assert judged.sum() >= len(at_0.times) - 6  # NaN until the noise patches hold a window
    np.testing.assert_allclose(above_fujii[judged], 200.0 * above_s2[judged], rtol=1e-6)
    assert np.all(above_fujii[judged] < fujii_0[judged])
    assert {"contrast", "contrast@noise", "im", "im@noise"} <= set(at_0.values["plate"])
    contrast, above_contrast = at_0.array("plate", "contrast"), at_0.array("plate", "contrast@noise")
    assert np.all(above_contrast[judged] < contrast[judged]) and np.all(above_contrast[judged] > 0.5 * contrast[judged])


def test_a_snippet_choosing_fujii_above_noise_is_a_daemon_config_with_thresholds_in_fujii_units(plate, passes):
    scene, frames, _ = plate
    series = passes[1.0]
    run = Run(lambda: iter(frames), FRAMES, 8, DT, None, WET_UNTIL, DRY_FROM, "plate")
    outcome = evaluate(Candidate("fujii", True, SETTING), series, WET_UNTIL, DRY_FROM, {"plate": 2.0}, DT, 1e-5)
    assert not isinstance(outcome, str)
    result = Result(run, series=[series], outcomes=[outcome], chosen=outcome, reason="Fujii above noise, chosen")
    config = _config(scene, q=1.0)  # an explicit q: the snippet must set q = 0 beside Fujii
    text = snippet(result, config, "edgedsm tune test")
    tuned = tomllib.loads(text)
    assert tuned["estimator"] == {"activity": "fujii", "window": 50, "lag": 5, "mode": "sliding",
                                  "noise_floor": True, "q": 0.0}
    data = {"camera": {"uri": f"sim:{scene}"}, "estimator": {"q": 1.0, **tuned["estimator"]},
            "regions": tuned["regions"]}
    daemon = validate(DaemonConfig, data, "<snippet>")
    assert daemon.estimator.activity == "fujii" and daemon.estimator.engine_q == 0.0
    (region,) = daemon.regions
    # the thresholds are between the dry and the wet Fujii above the noise (0..200 units), not S2's
    times, above = np.asarray(series.times), series.array("plate", "fujii@noise")
    wet, dry = above[(times <= WET_UNTIL) & np.isfinite(above)], above[times >= DRY_FROM]
    assert np.percentile(dry, 95) < region.dry_below < region.wet_above < np.percentile(wet, 5)
    assert region.wet_above > 2.0  # S2's would be below 1
    assert outcome.auc == 1.0 and outcome.delay_s is not None and abs(outcome.delay_s) < 10.0


def test_gd_asked_for_is_judged_like_the_daemon_in_the_window_modes_only(plate):
    scene, frames, masks = plate
    config = _config(scene)
    step, mask = 50, masks["plate"]
    series = run_pass(iter(frames), SETTING, config, masks, DT, step=step, bits=8, estimators=("gd",))
    gd = series.array("plate", "gd")
    ends = SETTING.window - 1 + step * np.arange(len(series.times))
    expected = [descriptors.gd(frames[end - SETTING.window + 1:end + 1])[mask].mean() for end in ends]
    np.testing.assert_allclose(gd, expected, rtol=1e-12)  # the daemon's region mean of the window's GD
    assert gd[0] > 2.0 * gd[-1] > 0  # wet to dry
    above = series.array("plate", "gd@noise")
    judged = np.isfinite(above)
    assert judged.sum() >= len(gd) - 1 and np.all(above[judged] < gd[judged])  # its floor taken off
    outcome = evaluate(Candidate("gd", True, SETTING), series, WET_UNTIL, DRY_FROM, {"plate": 2.0}, DT, 1e-3)
    assert not isinstance(outcome, str) and outcome.candidate.label() == "GD above noise, N=50 m=5 sliding"
    exponential = Setting(50, 5, "exponential")  # no window to read: GD is no candidate there
    assert [c.variant for c in candidates([SETTING, exponential], ("gd",))] == ["gd@noise", "gd"]
    other = run_pass(iter(frames[:120]), exponential, config, masks, DT, step=step, bits=8, estimators=("s2", "gd"))
    assert "gd" not in other.values["plate"] and "s2@noise" in other.values["plate"]
