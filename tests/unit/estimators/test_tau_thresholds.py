"""Drying thresholds in τc seconds carry over between window lengths and modes; S3 ones do not.

The drying demo scene (config/scenes/drying_demo.toml: τc grows from 3 Δt to 300 Δt, Δt = 50 ms),
slowed down (2400 frames of drying) and made small (48²), is run through the streaming engine
as the daemon runs it (τc sums snapshot -> region covariances -> pooled fit, S3 region mean)
with N = 100 and 400, sliding and tumbling, and a drying monitor judges each. Each observation
is stamped at the centre of its window, so that the different delays of the windows (N/2 frames)
do not count as a difference of the estimator. ``python tests/unit/estimators/test_tau_thresholds.py``
prints the table of docs/tau_c.md ("Thresholds in seconds").
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np
import pytest

from edgedsm.drying import DryingMonitor, Thresholds
from edgedsm.estimators import SlidingWindow
from edgedsm.estimators.snapshot import tau_covariances
from edgedsm.estimators.tau_stream import tau_region
from edgedsm.sim import Simulator, load_scene

REPO = Path(__file__).resolve().parents[3]
SIZE, FRAMES, DRYING_FRAMES = 48, 3000, 2400
LAG, MAX_LAG = 5, 20  # K·Δt = 1 s: τc is measured up to 1 s
EVERY = 20  # sliding: one evaluation a second (20 frames/s); tumbling: at each completed block
TAU = Thresholds.of_tau(wet_below_s=0.2, dry_above_s=0.5, hysteresis=0.05, min_dwell_s=0.0)
RUNS = ((100, "sliding"), (400, "sliding"), (100, "tumbling"), (400, "tumbling"))


@cache
def scene_frames() -> tuple[np.ndarray, float]:
    scene = load_scene(REPO / "config" / "scenes" / "drying_demo.toml")
    scene.scene.size = SIZE
    assert scene.activity.drying is not None
    scene.activity.drying.duration = DRYING_FRAMES  # slower drying: a 400-frame window sees τc x2, not x10
    simulator = Simulator(scene)
    return np.stack([simulator.next_frame() for _ in range(FRAMES)]), scene.scene.dt


@cache
def series(window: int, mode: str) -> list[tuple[float, float, float]]:
    """(window-centre time s, region τc s, region mean S3) at each evaluation."""
    frames, dt = scene_frames()
    engine = SlidingWindow((SIZE, SIZE), window=window, lag=LAG, q=1.0, estimators=("s3", "tau_c"), mode=mode,
                           max_lag=MAX_LAG)
    pixels = np.arange(SIZE * SIZE)  # the region: the whole frame
    out = []
    for seen, frame in enumerate(frames, start=1):
        engine.push(frame)
        due = seen % window == 0 if mode == "tumbling" else seen >= window and seen % EVERY == 0
        if not due:
            continue
        # as the daemon: the sums copied, covariances of the region's pixels, one pooled fit
        cov, var = tau_covariances(engine.tau_snapshot(), pixels)
        tau = tau_region(window, MAX_LAG, cov, var)
        out.append(((seen - window / 2) * dt, float(tau.tau) * dt, float(engine.maps()["s3"].mean())))
    return out


def transitions(window: int, mode: str, thresholds: Thresholds, column: int) -> list[tuple[str, float]]:
    """(state entered, window-centre time s) of a drying monitor fed one column of ``series``."""
    monitor = DryingMonitor({"plate": thresholds})
    moves = []
    for row in series(window, mode):
        for transition in monitor.step(row[0], {"plate": row[column]}):
            moves.append((transition.to_state.value, transition.t))
    return moves


def s3_thresholds_matching_tau() -> Thresholds:
    """The S3 thresholds that reproduce the τc states at N = 100, sliding (calibrated on one
    setting, as a user would): S3 where the τc monitor left wet and entered dry, over (1 - h),
    since wet is left and dry entered at the threshold x (1 - h)."""
    rows = {t: s3 for t, _, s3 in series(100, "sliding")}
    moves = dict(transitions(100, "sliding", TAU, 1)[1:])
    h = TAU.hysteresis
    return Thresholds(wet_above=rows[moves["drying"]] / (1 - h), dry_below=rows[moves["dry"]] / (1 - h),
                      hysteresis=h, min_dwell_s=0.0)


def table() -> list[tuple[int, str, list[tuple[str, float]], list[tuple[str, float]]]]:
    s3 = s3_thresholds_matching_tau()
    return [(n, mode, transitions(n, mode, TAU, 1), transitions(n, mode, s3, 2)) for n, mode in RUNS]


@pytest.mark.slow
def test_tau_thresholds_give_the_same_states_for_any_window_and_mode() -> None:
    reference = transitions(100, "sliding", TAU, 1)
    assert [state for state, _ in reference] == ["wet", "drying", "dry"]
    _, dt = scene_frames()
    for window, mode in RUNS:
        moves = transitions(window, mode, TAU, 1)
        assert [state for state, _ in moves] == ["wet", "drying", "dry"], (window, mode, moves)
        # sliding: observed every second; tumbling: once per block (its time resolution is N·Δt)
        tolerance = 4.0 if mode == "sliding" else window * dt
        for (_, t), (_, t_ref) in zip(moves[1:], reference[1:], strict=True):
            assert abs(t - t_ref) <= tolerance, (window, mode, moves, reference)


@pytest.mark.slow
def test_the_same_s3_thresholds_do_not_carry_over_from_100_to_400_frames() -> None:
    s3 = s3_thresholds_matching_tau()
    at_100 = transitions(100, "sliding", s3, 2)
    tau_at_100 = transitions(100, "sliding", TAU, 1)
    # calibrated there, S3 reproduces τc's states at N = 100 ...
    assert [state for state, _ in at_100] == ["wet", "drying", "dry"]
    assert [state for state, _ in at_100] == [state for state, _ in tau_at_100]
    assert all(abs(a[1] - b[1]) <= 1.0 for a, b in zip(at_100, tau_at_100, strict=True))  # one evaluation
    # ... but at N = 400 S3 is lower at the same τc (σ over a longer window is larger): the surface
    # is never "wet" at all, and "dry" comes ten seconds and more before τc says so
    at_400 = transitions(400, "sliding", s3, 2)
    tau_at_400 = transitions(400, "sliding", TAU, 1)
    assert next(state for state, _ in at_400) != "wet"
    dry_s3 = next(t for state, t in at_400 if state == "dry")
    dry_tau = next(t for state, t in tau_at_400 if state == "dry")
    assert dry_tau - dry_s3 >= 10.0, (at_400, tau_at_400)


@pytest.mark.parametrize(("window", "mode"), [(100, "sliding"), (400, "tumbling")])
def test_the_daemon_path_equals_the_engine_region_tau(window: int, mode: str) -> None:
    frames, _ = scene_frames()
    engine = SlidingWindow((SIZE, SIZE), window=window, lag=LAG, estimators=("s3", "tau_c"), mode=mode,
                           max_lag=MAX_LAG)
    for frame in frames[:window + 37]:
        engine.push(frame)
    mask = np.zeros((SIZE, SIZE), bool)
    mask[5:30, 8:40] = True
    cov, var = tau_covariances(engine.tau_snapshot(), np.flatnonzero(mask))
    assert tau_region(window, MAX_LAG, cov, var) == engine.region_tau_c(mask)
    assert engine.region_tau_c(mask).status == 0  # measured: a real value is compared


if __name__ == "__main__":
    print("| N | mode | τc thresholds (0.2 s / 0.5 s) | S3 thresholds (calibrated at N = 100 sliding) |")
    print("|---:|---|---|---|")
    for n, mode, tau_moves, s3_moves in table():
        def text(moves: list[tuple[str, float]]) -> str:
            return ", ".join(f"{state} {t:.1f} s" for state, t in moves)
        print(f"| {n} | {mode} | {text(tau_moves)} | {text(s3_moves)} |")
    print("S3 thresholds:", s3_thresholds_matching_tau())
