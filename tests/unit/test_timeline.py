"""`edgedsm analyze --timeline`: activity against time from a small simulated drying scene."""

from __future__ import annotations

import csv
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from edgedsm.cli import main
from edgedsm.errors import EstimatorError
from edgedsm.measurement.judge import REFRESH_EVERY
from edgedsm.timeline import timeline

ROOT = Path(__file__).resolve().parents[2]


def small_drying_scene(folder: Path) -> Path:
    """config/scenes/drying_demo.toml at 32² with the drying moved to frames 100…400."""
    data = tomllib.loads((ROOT / "config/scenes/drying_demo.toml").read_text())
    data["scene"]["size"] = 32
    data["activity"]["drying"].update(start=100, duration=300)
    lines = []
    for section, table in data.items():
        scalars = {k: v for k, v in table.items() if not isinstance(v, dict)}
        lines.append(f"[{section}]")
        lines += [f"{k} = {v!r}".replace("'", '"') for k, v in scalars.items()]
        for name, sub in table.items():
            if isinstance(sub, dict):
                lines.append(f"[{section}.{name}]")
                lines += [f"{k} = {v!r}".replace("'", '"') for k, v in sub.items()]
    path = folder / "drying_small.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def read_rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


def test_timeline_of_a_drying_scene_falls(tmp_path: Path) -> None:
    scene = small_drying_scene(tmp_path)
    out = tmp_path / "out"
    assert main(["analyze", str(scene), "--frames", "480", "--timeline", str(out), "--window", "50",
                 "--lag", "2", "--every", "10"]) == 0
    rows = read_rows(out / "timeline.csv")
    assert [row["region"] for row in rows] == ["frame"] * 44  # frames 49, 59, ..., 479
    assert rows[0]["frame"] == "49" and float(rows[0]["time_s"]) == pytest.approx(49 * 0.05)
    early, late = rows[:4], rows[-4:]  # before the drying starts / after it ended (τc 3 -> 300)
    for column in ("s1", "s2"):
        before = np.mean([float(r[column]) for r in early])
        after = np.mean([float(r[column]) for r in late])
        assert after < 0.5 * before, column
    assert float(early[0]["tau_c_frames"]) == pytest.approx(3.0, rel=0.25)  # the scene's τc before drying
    assert early[0]["tau_c_status"] == "measured" and late[-1]["tau_c_status"] == "above"
    assert float(late[-1]["tau_c_s"]) == pytest.approx(20 * 0.05)  # K·Δt: a lower bound
    for picture in ("timeline.png", "histogram.png"):
        assert (out / picture).stat().st_size > 10_000


def test_timeline_regions_from_a_config(tmp_path: Path) -> None:
    frames = np.random.default_rng(0).integers(0, 256, (40, 24, 24), dtype=np.uint8)
    frames[:, :, 12:] //= 8  # the right half is much quieter
    np.save(tmp_path / "frames.npy", frames)
    config = tmp_path / "edgedsm.toml"
    region = '[[regions]]\nname = "{}"\nshape = "rect"\nx = {}\ny = 0\nwidth = 12\nheight = 24\n' \
             'wet_above = 0.3\ndry_below = 0.1\n\n'
    config.write_text('[camera]\nuri = "sim:default"\nframe_interval_s = 0.1\n\n'
                      + region.format("left", 0) + region.format("right", 12))
    out = tmp_path / "out"
    assert main(["analyze", str(tmp_path / "frames.npy"), "--timeline", str(out), "-c", str(config),
                 "--window", "20", "--lag", "1", "--every", "5", "--max-lag", "5"]) == 0
    rows = read_rows(out / "timeline.csv")
    assert {row["region"] for row in rows} == {"left", "right"}
    assert len(rows) == 2 * 5  # samples at frames 19, 24, 29, 34, 39
    assert float(rows[-1]["time_s"]) == pytest.approx(3.9)  # Δt from the config's camera
    left = [float(r["s1"]) for r in rows if r["region"] == "left"]
    right = [float(r["s1"]) for r in rows if r["region"] == "right"]
    assert min(left) > 5 * max(right)


def test_timeline_refuses_too_few_frames() -> None:
    frames = [np.zeros((8, 8), np.uint8) + i for i in range(5)]
    with pytest.raises(EstimatorError, match="5 frames do not fill one window of N = 10"):
        timeline(frames, {"frame": np.ones((8, 8), bool)}, window=10, lag=1, every=1, max_lag=5)


def test_disjoint_sets_run_tumbling_with_the_sliding_windows_values() -> None:
    # every = N: the samples are disjoint sets of N frames (the paper's Figs. 10-11); the
    # tumbling engine gives the same region values as a sliding one at those frames
    rng = np.random.default_rng(5)
    frames = rng.poisson(40.0, size=(96, 24, 24)).astype(np.uint8)
    regions = {"left": np.zeros((24, 24), bool), "all": np.ones((24, 24), bool)}
    regions["left"][:, :12] = True
    auto = timeline(iter(frames), regions, window=32, lag=2, every=32, max_lag=4)
    sliding = timeline(iter(frames), regions, window=32, lag=2, every=32, max_lag=4, mode="sliding")
    assert [row[:3] for row in auto.rows] == [row[:3] for row in sliding.rows] and len(auto.rows) == 6
    for a, b in zip(auto.rows, sliding.rows, strict=True):
        np.testing.assert_allclose(a[3:7], b[3:7], rtol=1e-12)
        assert a[8] == b[8]


def test_a_disjoint_timeline_holds_m_frames_not_n() -> None:
    # tumbling keeps the lag's frames, not the window's: a 10x longer window barely grows memory
    import tracemalloc

    rng = np.random.default_rng(6)
    frames = rng.integers(0, 255, size=(400, 64, 64), dtype=np.uint8)
    regions = {"all": np.ones((64, 64), bool)}
    # (the noise patches keep N frames of a 64² square per region whatever the frame size, here the
    # whole 64² frame: left out, they are not the engine's memory)
    for window in (40, 400):  # one-time allocations (and compiling) first
        timeline(iter(frames[:window]), regions, window=window, lag=2, every=window, max_lag=4, with_noise=False)
    peaks = []
    for window in (40, 400):
        tracemalloc.start()
        timeline(iter(frames[:window]), regions, window=window, lag=2, every=window, max_lag=4, with_noise=False)
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
    ring = 64 * 64 * 360  # what 360 more frames of a sliding ring would hold (a sliding timeline grows by it)
    assert peaks[1] - peaks[0] < ring / 4, peaks


def test_without_tau_c_the_same_activity_and_tau_columns_off(tmp_path: Path) -> None:
    scene = small_drying_scene(tmp_path)
    runs = {}
    for name, extra in (("with", []), ("without", ["--no-tau-c"])):
        out = tmp_path / name
        assert main(["analyze", str(scene), "--frames", "160", "--timeline", str(out), "--window", "50",
                     "--lag", "2", "--every", "50", *extra]) == 0
        runs[name] = read_rows(out / "timeline.csv")
    assert len(runs["with"]) == len(runs["without"]) == 3
    for a, b in zip(runs["with"], runs["without"], strict=True):
        assert [a[c] for c in ("frame", "s1", "s2", "s3")] == [b[c] for c in ("frame", "s1", "s2", "s3")]
        assert a["tau_c_status"] != "off" and b["tau_c_status"] == "off" and b["tau_c_frames"] == "nan"


def test_disjoint_sets_too_long_for_pooled_int64_sums_take_the_engines_tau(monkeypatch: pytest.MonkeyPatch) -> None:
    # windows whose window-end sums would leave int64 (16-bit N > 23 170) take τc from the engine:
    # the same values, to rounding
    import edgedsm.timeline as module
    from edgedsm.estimators.tau_regions import int64_problem

    assert int64_problem((8, 8), 23_000, 16) is None and "too long" in int64_problem((8, 8), 24_000, 16)
    rng = np.random.default_rng(8)
    frames = rng.poisson(40.0, size=(64, 16, 16)).astype(np.uint8)
    regions = {"all": np.ones((16, 16), bool)}
    pooled = timeline(iter(frames), regions, window=32, lag=2, every=32, max_lag=6)
    monkeypatch.setattr(module, "int64_problem", lambda *args: "too long")
    engine = timeline(iter(frames), regions, window=32, lag=2, every=32, max_lag=6)
    for a, b in zip(pooled.rows, engine.rows, strict=True):
        np.testing.assert_allclose(a[6], b[6], rtol=1e-12)
        assert a[8] == b[8]


def test_the_light_and_the_activity_above_the_noise_follow_a_darkening_film(tmp_path: Path) -> None:
    scene = Path(__file__).resolve().parents[2] / "config" / "scenes" / "darkening_film.toml"
    small = tmp_path / "film.toml"
    small.write_text(scene.read_text().replace("size = 128", "size = 48"))
    out = tmp_path / "out"
    assert main(["analyze", str(small), "--timeline", str(out), "--window", "100", "--lag", "5",
                 "--every", "25", "--estimator", "s2", "--no-progress"]) == 0
    rows = read_rows(out / "timeline.csv")
    assert len(rows) == 45
    light = [float(r["mean_intensity"]) for r in rows]
    assert light[-1] < light[0] / 5  # the film's light fell (to a tenth by the end)
    above = [float(r["s2_above_noise"]) for r in rows]
    plain = [float(r["s2"]) for r in rows]
    # the daemon's judge looks for a model from the frames at its first sample and every REFRESH_EVERY
    # after: the wet film's first fails, the next (the activity slower) holds
    first = next(index for index, value in enumerate(above) if math.isfinite(value))
    assert first == REFRESH_EVERY and all(math.isfinite(a) for a in above[first:])
    assert above[-1] < 0.5 * plain[-1] and above[-1] < above[first] / 4  # most of the dry film's S2 is noise
    assert {r["signal"] for r in rows} <= {"ok", "low"} and {r["noise_view"] for r in rows} == {"region"}
    # the judged value is S2 above its floor where there is one, the plain S2 before
    judged = [float(r["activity"]) for r in rows]
    assert judged[:first] == pytest.approx(plain[:first], rel=1e-5)
    assert judged[first:] == pytest.approx(above[first:], rel=1e-5)
    off = tmp_path / "off"
    assert main(["analyze", str(small), "--timeline", str(off), "--window", "100", "--lag", "5", "--every", "100",
                 "--no-noise-floor", "--no-tau-c", "--no-progress"]) == 0
    assert {r["signal"] for r in read_rows(off / "timeline.csv")} == {"off"}


def test_a_timeline_judges_every_pixel_of_a_region_unless_its_window_is_large(monkeypatch: pytest.MonkeyPatch) -> None:
    rng = np.random.default_rng(5)
    frames = rng.poisson(rng.exponential(60.0, (40, 40)), (60, 40, 40)).clip(0, 255).astype(np.uint8)
    regions = {"all": np.ones((40, 40), bool)}
    whole = timeline(iter(frames), regions, window=50, lag=2, every=10, with_tau=False)
    assert {row[whole.columns.index("noise_view")] for row in whole.rows} == {"region"}
    monkeypatch.setattr("edgedsm.timeline.REGION_VIEW_SAMPLES", 50 * 40 * 40 - 1)  # one pixel-frame too many
    patched = timeline(iter(frames), regions, window=50, lag=2, every=10, with_tau=False)
    views = {row[patched.columns.index("noise_view")] for row in patched.rows}
    assert views == {"patch 64x64 px at the region's centre"}
    # a 64-px patch of a 40-px region is the whole region: the same numbers, named otherwise
    floor = whole.columns.index("noise_floor")
    assert [row[floor] for row in patched.rows] == pytest.approx([row[floor] for row in whole.rows], rel=1e-12)


@pytest.mark.parametrize(("activity", "estimator", "judged"), [
    ("s3", None, "s3"),       # no --estimator: the config's activity, what the daemon judges
    ("tau_c", None, "tau_c"),
    ("s3", "s1", "s1"),       # an explicit --estimator wins
    (None, None, "s2"),       # no config: the daemon's default activity
])
def test_the_judged_column_is_the_configs_activity_unless_named(tmp_path: Path, activity, estimator, judged) -> None:
    np.save(tmp_path / "frames.npy", np.random.default_rng(1).integers(0, 256, (30, 16, 16), dtype=np.uint8))
    args = ["analyze", str(tmp_path / "frames.npy"), "--timeline", str(tmp_path / "out"), "--window", "20",
            "--lag", "1", "--every", "10", "--max-lag", "5", "--no-progress"]
    if activity is not None:
        thresholds = "wet_below_s = 0.2\ndry_above_s = 1.0\n" if activity == "tau_c" else \
            "wet_above = 0.3\ndry_below = 0.1\n"
        config = tmp_path / "edgedsm.toml"
        config.write_text(f'[camera]\nuri = "sim:default"\nframe_interval_s = 0.1\n\n[estimator]\n'
                          f'activity = "{activity}"\n\n[[regions]]\nname = "all"\nshape = "full"\n{thresholds}')
        args += ["-c", str(config)]
    if estimator is not None:
        args += ["--estimator", estimator]
    assert main(args) == 0
    assert {row["estimator"] for row in read_rows(tmp_path / "out" / "timeline.csv")} == {judged}
