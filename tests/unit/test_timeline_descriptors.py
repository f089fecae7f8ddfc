"""`analyze --timeline` with the field's streaming descriptors (issue 24): the temporal contrast,
Fujii, the inertia moment and the generalized differences as region-mean columns, equal to the
batch references of each window (sliding) or set (tumbling)."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from edgedsm.cli import main
from edgedsm.errors import EstimatorError
from edgedsm.estimators import bands, descriptors, registry
from edgedsm.estimators.registry import Record
from edgedsm.timeline import COLUMNS, analysis_config, timeline
from tests.unit.test_timeline import small_drying_scene


def test_descriptor_columns_are_the_region_means_of_each_windows_maps() -> None:
    rng = np.random.default_rng(4)
    frames = rng.integers(0, 256, (40, 12, 16), dtype=np.uint8)
    frames[:, :3] = 0  # a dark band: contrast defined as 0 there, never NaN
    left = np.zeros((12, 16), bool)
    left[:, :8] = True
    regions = {"left": left, "right": ~left}
    result = timeline(iter(frames), regions, window=10, lag=2, every=6, with_tau=False, with_noise=False,
                      descriptors=("gd", "im", "contrast", "fujii"), histogram_estimator="contrast")
    assert result.columns == (*COLUMNS, "contrast", "fujii", "im", "gd")  # in the descriptors' own order
    assert len(result.rows) == 2 * 6  # frames 9, 15, ..., 39
    for row in result.rows:
        index, name = row[0], row[2]
        window, mask = frames[index - 9:index + 1], regions[name]
        values = dict(zip(result.columns, row, strict=True))
        assert values["contrast"] == pytest.approx(descriptors.contrast(window)[mask].mean(), rel=1e-13)
        assert values["im"] == pytest.approx(descriptors.im(window, 2)[mask].mean(), rel=1e-13)
        assert values["fujii"] == pytest.approx(descriptors.fujii(window, 2)[mask].mean(), rel=1e-12)
        assert values["fujii"] == pytest.approx(200 * values["s2"], rel=1e-13)  # the timeline's q is 0
        assert values["gd"] == pytest.approx(descriptors.gd(window)[mask].mean(), rel=1e-13)
        assert all(np.isfinite(values[key]) for key in ("contrast", "fujii", "im", "gd"))
    assert result.histogram_estimator == "contrast" and len(result.histograms) == 6


def test_gd_column_of_disjoint_sets_comes_from_the_tumbling_engine() -> None:
    rng = np.random.default_rng(5)
    frames = rng.integers(0, 4096, (50, 8, 10), dtype=np.uint16)
    regions = {"all": np.ones((8, 10), bool)}
    result = timeline(iter(frames), regions, window=10, lag=1, every=10, bits=12, with_tau=False, with_noise=False,
                      descriptors=("gd",), histogram_estimator="gd")  # every = N: the paper's sets, tumbling
    assert [row[0] for row in result.rows] == [9, 19, 29, 39, 49]
    for row in result.rows:
        expected = descriptors.gd(frames[row[0] - 9:row[0] + 1]).mean()
        assert row[-1] == pytest.approx(expected, rel=1e-13) and 1000 < row[-1] < 1700  # ~4096/3 for uniform data
    assert len(result.histograms) == 5


def test_unknown_descriptors_and_histograms_of_maps_not_followed_are_refused() -> None:
    frames = np.zeros((12, 4, 4), np.uint8)
    regions = {"all": np.ones((4, 4), bool)}
    with pytest.raises(EstimatorError, match="not \\['mhi'\\]"):
        timeline(iter(frames), regions, window=10, lag=1, every=1, descriptors=("mhi",))
    with pytest.raises(EstimatorError, match="histogram estimator must be one of s1, s2, s3, got 'im'"):
        timeline(iter(frames), regions, window=10, lag=1, every=1, histogram_estimator="im")


def test_analyze_timeline_follows_the_estimator_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scene = small_drying_scene(tmp_path)
    out = tmp_path / "out"
    assert main(["analyze", str(scene), "--frames", "480", "--timeline", str(out), "--window", "50", "--lag", "2",
                 "--every", "10", "--estimator", "contrast", "--no-tau-c", "--no-noise-floor"]) == 0
    with (out / "timeline.csv").open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert list(rows[0])[-1] == "contrast" and "fujii" not in rows[0]
    early = np.mean([float(r["contrast"]) for r in rows[:4]])
    late = np.mean([float(r["contrast"]) for r in rows[-4:]])
    assert 0.5 < early < 0.8 and late < 0.75 * early  # σ/⟨I⟩ falls as the film dries
    assert (out / "timeline.png").stat().st_size > 10_000
    assert main(["analyze", str(scene), "--frames", "60", "--timeline", str(out), "--window", "50",
                 "--estimator", "mhi"]) == 1
    assert "mhi is a batch map only" in capsys.readouterr().err


@pytest.mark.parametrize(("activity", "reference", "apart"), [
    ("im", lambda window: descriptors.im(window, 1), 10),  # differences 4x smaller: IM about 16x
    ("gd", descriptors.gd, 3),  # GD about 4x
])
def test_the_configs_activity_adds_its_column(tmp_path: Path, activity, reference, apart) -> None:
    frames = np.random.default_rng(1).integers(0, 256, (30, 16, 16), dtype=np.uint8)
    frames[:, :, 8:] //= 4  # the right half: differences 4x smaller
    np.save(tmp_path / "frames.npy", frames)
    config = tmp_path / "edgedsm.toml"
    region = '[[regions]]\nname = "{}"\nshape = "rect"\nx = {}\ny = 0\nwidth = 8\nheight = 16\n' \
             'wet_above = 400.0\ndry_below = 50.0\n\n'
    config.write_text(f'[camera]\nuri = "sim:default"\n\n[estimator]\nactivity = "{activity}"\n\n'
                      + region.format("left", 0) + region.format("right", 8))
    out = tmp_path / "out"
    assert main(["analyze", str(tmp_path / "frames.npy"), "--timeline", str(out), "-c", str(config), "--window",
                 "10", "--lag", "1", "--every", "10", "--no-tau-c", "--no-noise-floor"]) == 0
    with (out / "timeline.csv").open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert list(rows[0])[-1] == activity and len(rows) == 2 * 3  # frames 9, 19, 29
    for row in rows:
        index, x = int(row["frame"]), 0 if row["region"] == "left" else 8
        expected = reference(frames[index - 9:index + 1, :, x:x + 8]).mean()
        assert float(row[activity]) == pytest.approx(expected, rel=1e-5)  # the CSV keeps 6 digits
    left = [float(r[activity]) for r in rows if r["region"] == "left"]
    right = [float(r[activity]) for r in rows if r["region"] == "right"]
    assert min(left) > apart * max(right)


@pytest.mark.parametrize("every", [4, 16])  # sliding, and tumbling (every a multiple of N)
def test_band_columns_are_the_region_means_of_the_batch_bands(every: int) -> None:
    rng = np.random.default_rng(9)
    t = np.arange(64)[:, None, None]
    slow = 100 + 60 * np.cos(2 * np.pi * 0.05 * t) + rng.normal(0, 5, (64, 8, 8))  # 2.5 Hz at 50 frames/s
    fast = 100 + 60 * np.cos(2 * np.pi * 0.4 * t) + rng.normal(0, 5, (64, 8, 8))  # 20 Hz
    frames = np.clip(np.concatenate([slow, fast], axis=2), 0, 255).astype(np.uint8)
    left = np.zeros((8, 16), bool)
    left[:, :8] = True
    regions = {"slow": left, "fast": ~left}
    result = timeline(iter(frames), regions, window=16, lag=1, every=every, dt=0.02, with_tau=False,
                      with_noise=False, descriptors=("band_ratio", "band_low"), band_split=10.0,
                      histogram_estimator="band_ratio")
    assert result.columns == (*COLUMNS, "band_low", "band_ratio")
    for row in result.rows:
        index, name = row[0], row[2]
        window, mask = frames[index - 15:index + 1], regions[name]
        values = dict(zip(result.columns, row, strict=True))
        low, high = bands.split_powers(window, 0.02, 10.0)
        assert values["band_low"] == pytest.approx(low[mask].mean(), rel=1e-9)
        assert values["band_ratio"] == pytest.approx(bands.ratio(low, high)[mask].mean(), rel=1e-9)
    ratios = {name: result.series(name, "band_ratio") for name in regions}
    assert (ratios["slow"] < 0.1).all() and (ratios["fast"] > 10).all()


def test_analyze_timeline_follows_the_band_ratio(tmp_path: Path) -> None:
    frames = np.random.default_rng(2).integers(0, 256, (40, 8, 8), dtype=np.uint8)
    np.save(tmp_path / "frames.npy", frames)
    out = tmp_path / "out"
    assert main(["analyze", str(tmp_path / "frames.npy"), "--timeline", str(out), "--window", "16", "--every", "8",
                 "--estimator", "band_ratio", "--dt", "0.02", "--split", "5", "--no-tau-c", "--no-noise-floor"]) == 0
    with (out / "timeline.csv").open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert list(rows[0])[-1] == "band_ratio" and len(rows) == 4
    window = frames[39 - 15:40]
    expected = bands.ratio(*bands.split_powers(window, 0.02, 5.0)).mean()
    assert float(rows[-1]["band_ratio"]) == pytest.approx(expected, rel=1e-5)  # the CSV keeps 6 digits


def test_the_configs_band_ratio_and_split_give_the_column(tmp_path: Path) -> None:
    frames = np.random.default_rng(3).integers(0, 256, (40, 8, 8), dtype=np.uint8)
    np.save(tmp_path / "frames.npy", frames)
    config = tmp_path / "edgedsm.toml"
    config.write_text('[camera]\nuri = "sim:default"\nframe_interval_s = 0.02\n\n[estimator]\nactivity = "band_ratio"\n'
                      'window = 16\nlag = 1\nband_split_hz = 5.0\n\n[[regions]]\nname = "all"\nshape = "rect"\nx = 0\n'
                      'y = 0\nwidth = 8\nheight = 8\nwet_above = 2.0\ndry_below = 1.0\n')
    out = tmp_path / "out"
    assert main(["analyze", str(tmp_path / "frames.npy"), "--timeline", str(out), "-c", str(config), "--window",
                 "16", "--every", "8", "--no-tau-c", "--no-noise-floor"]) == 0
    with (out / "timeline.csv").open(newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert list(rows[0])[-1] == "band_ratio" and len(rows) == 4
    for row in rows:  # the config's Δt (0.02 s) and split (5 Hz): 3 of the 8 bins in the low band
        index = int(row["frame"])
        expected = bands.ratio(*bands.split_powers(frames[index - 15:index + 1], 0.02, 5.0)).mean()
        assert float(row["band_ratio"]) == pytest.approx(expected, rel=1e-5)


def test_the_q_analyzed_is_the_records_not_a_name_test() -> None:
    """A map formed at q = 0 (its record's needs_q_zero) is analysed at q = 0 whatever q is asked,
    every other at the q asked; a new record with the property is formed at 0 too, by no name."""
    for name in registry.activities():
        config = analysis_config(window=20, lag=2, q=3.0, mode="sliding", activity=name)
        assert config.estimator.q == (0.0 if registry.get(name).needs_q_zero else 3.0), name
        assert config.estimator.engine_q == config.estimator.q, name
    assert [name for name in registry.activities() if registry.get(name).needs_q_zero] == ["fujii"]
    twin = Record("fujii_twin", "1 (0..200)", "Fujii twin", "200 S2(q = 0)", "derived", frozenset({"ratio"}),
                  ("s2",), frozenset(registry.MODES), uses_lag=True, needs_q_zero=True,
                  derive="edgedsm.estimators.activity:fujii_values")
    assert twin.q_for(3.0) == 0.0 and registry.get("s2").q_for(3.0) == 3.0
