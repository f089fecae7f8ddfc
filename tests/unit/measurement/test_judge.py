"""The measurement core's signal judge, which the daemon's evaluator, analyze and tune run
(docs/noise.md, §5c): what a region is judged on, when its state is held, the warnings, the model
and the floors it keeps."""

from __future__ import annotations

import numpy as np
import pytest

from edgedsm.config import DaemonConfig
from edgedsm.estimators import s1, s2, s3
from edgedsm.estimators.noise_summary import region_floor
from edgedsm.measurement.judge import REFRESH_EVERY, SignalJudge
from edgedsm.noise_patches import PatchWindow
from edgedsm.validation import validate


def _config(activity="s2", camera_noise=None, **estimator) -> DaemonConfig:
    camera = {"uri": "sim:default", **({"noise": camera_noise} if camera_noise else {})}
    return validate(DaemonConfig, {"camera": camera, "estimator": {"window": 60, "lag": 2, "activity": activity,
                                                                   **estimator},
                                   "regions": [{"name": "a", "wet_above": 0.3, "dry_below": 0.05}]}, "<judge>")


def _static(mean=80.0, frames=60, side=32, seed=0, top=255):
    """A static speckle pattern under shot noise (gain 0.5 DN/e⁻): only noise fluctuates."""
    rng = np.random.default_rng(seed)
    pattern = rng.exponential(mean, (side, side))
    electrons = rng.poisson(np.broadcast_to(pattern / 0.5, (frames, side, side)))
    return np.clip(np.rint(electrons * 0.5), 0, top).astype(np.uint8)


def _estimates(frames, lag=2, q=1.0):
    return {"s1": float(s1(frames, lag).mean()), "s2": float(s2(frames, lag, q=q).mean()),
            "s3": float(s3(frames, lag).mean())}


def _patch(frames):
    return PatchWindow(frames, np.ones(frames.shape[1:], bool), 255.0)


def test_a_static_surface_is_judged_on_its_activity_above_the_floor_near_zero():
    judge = SignalJudge.of(_config(camera_noise={"gain": 0.5}))
    frames = _static()
    estimates = _estimates(frames)
    assert judge.assess({"a": _patch(frames)}, {"a": estimates}) == []
    signal = judge.signals["a"]
    assert signal.noise_model == "datasheet" and signal.signal == "low"
    assert signal.noise_floor == pytest.approx(estimates["s2"], rel=0.05)  # the noise is all there is
    judged = judge.judged("a", estimates["s2"], estimates)
    assert judged == pytest.approx(estimates["s2"] - signal.noise_floor) and abs(judged) < 3 * signal.above_noise_spread


def test_saturated_light_holds_the_state_with_one_warning_cleared_when_it_recovers():
    judge = SignalJudge.of(_config(camera_noise={"gain": 0.5}))
    frames = _static()
    bright = np.minimum(frames.astype(np.int32) * 4, 255).astype(np.uint8)
    estimates, bright_estimates = _estimates(frames), _estimates(bright)
    judge.assess({"a": _patch(frames)}, {"a": estimates})
    began = judge.assess({"a": _patch(bright)}, {"a": bright_estimates})
    held = [w for w in began if w.holds]
    assert len(held) == 1 and held[0].active and held[0].reason.startswith("signal saturated: ")
    assert judge.signals["a"].signal == "saturated"
    assert judge.judged("a", bright_estimates["s2"], bright_estimates) is None
    assert [w for w in judge.assess({"a": _patch(bright)}, {"a": bright_estimates}) if w.holds] == []  # not again
    cleared = judge.assess({"a": _patch(frames)}, {"a": estimates})
    assert any(not w.active and w.reason.startswith("cleared: signal saturated") for w in cleared)
    assert judge.judged("a", estimates["s2"], estimates) is not None


def test_an_intensity_change_beyond_the_factor_warns_once_each_way():
    judge = SignalJudge.of(_config(camera_noise={"gain": 0.5}, intensity_change=2.0))
    frames = _static(mean=80.0)
    dim = _static(mean=30.0, seed=1)
    judge.assess({"a": _patch(frames)}, {"a": _estimates(frames)})
    fell = judge.assess({"a": _patch(dim)}, {"a": _estimates(dim)})
    assert [(w.active, w.reason.split(" since")[0]) for w in fell] == [
        (True, f"mean intensity fell {frames.mean() / dim.mean():.3g}×")]
    assert judge.signals["a"].intensity_change == pytest.approx(dim.mean() / frames.mean(), rel=0.01)
    back = judge.assess({"a": _patch(frames)}, {"a": _estimates(frames)})
    assert [w.active for w in back] == [False]


def test_without_a_model_the_plain_activity_is_judged_and_the_reason_says_why():
    judge = SignalJudge.of(_config())
    rng = np.random.default_rng(3)
    fast = rng.integers(0, 200, (60, 32, 32)).astype(np.uint8)  # decorrelates every frame: no noise to tell apart
    estimates = _estimates(fast)
    judge.assess({"a": _patch(fast)}, {"a": estimates})
    assert judge.model is None and judge.signals["a"].above_noise is None
    assert "no noise model" in judge.signals["a"].reason
    assert judge.judged("a", estimates["s2"], estimates) == estimates["s2"]


def test_a_model_from_the_frames_is_kept_and_a_floor_reused_while_the_light_holds():
    judge = SignalJudge.of(_config())
    frames = _static(frames=120)
    estimates = _estimates(frames)
    judge.assess({"a": _patch(frames)}, {"a": estimates})
    model, floor = judge.model, judge.floor("a")
    assert model is not None and model.source == "frames"
    judge.assess({"a": _patch(frames)}, {"a": estimates})
    assert judge.model is model and judge.floor("a") is floor  # nothing recomputed
    for _ in range(REFRESH_EVERY):
        judge.assess({"a": _patch(frames)}, {"a": estimates})
    assert judge.floor("a") is not floor  # refreshed at least every REFRESH_EVERY assessments


def test_s3_above_the_noise_follows_the_current_s1_between_two_assessments():
    judge = SignalJudge.of(_config(activity="s3", camera_noise={"gain": 0.5}))
    rng = np.random.default_rng(5)
    a, b = rng.exponential(80.0, (2, 32, 32))
    turn = np.linspace(0.0, 6 * np.pi, 60)[:, None, None]  # two patterns turning into each other
    clean = a * np.cos(turn) ** 2 + b * np.sin(turn) ** 2
    frames = np.clip(np.rint(rng.poisson(clean / 0.5) * 0.5), 0, 255).astype(np.uint8)
    estimates = _estimates(frames)
    judge.assess({"a": _patch(frames)}, {"a": estimates})
    floor = region_floor(frames, "s3", 2, judge.model, q=1.0, top=255.0)
    kept = judge.floor("a")
    assert kept.floor == floor.floor and kept.noise_variance == floor.noise_variance and kept.share == floor.share
    now = judge.judged("a", estimates["s3"], estimates)
    assert now == judge.signals["a"].above_noise and 0.0 < now < estimates["s3"]
    closer = judge.judged("a", estimates["s3"], {**estimates, "s1": 0.5 * (estimates["s1"] + kept.floor.value)})
    assert 0.0 <= closer < now  # S1 nearer its floor: less of S3 is signal
