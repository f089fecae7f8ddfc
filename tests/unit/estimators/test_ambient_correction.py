"""The ambient correction of S2 (edgedsm.estimators.ambient) and its benchmark on the simulator."""

from __future__ import annotations

import numpy as np
import pytest

from edgedsm.cli import main
from edgedsm.errors import EstimatorError
from edgedsm.estimators import s2
from edgedsm.estimators.ambient import ambient_corrected_s2, dark_statistics, mean_square_difference
from edgedsm_lab.bench.ambient import Case, beats_plain, measure


def _speckle(rng: np.random.Generator, n: int = 400, size: int = 24) -> np.ndarray:
    """Exponential (fully developed) speckle intensities, independent frames, mean 200."""
    return rng.exponential(200.0, (n, size, size))


def test_identity_without_ambient_light() -> None:
    frames = _speckle(np.random.default_rng(1))
    plain = s2(frames, 1)
    corrected = ambient_corrected_s2(plain, frames.mean(axis=0), mean_square_difference(frames, 1), 0.0, 0.0)
    np.testing.assert_array_equal(corrected, plain)


def test_recovers_s2_of_the_laser_light_under_poisson_ambient_light() -> None:
    rng = np.random.default_rng(2)
    laser = _speckle(rng)
    ambient = 60.0  # photons: 30 % of the mean laser level, shot noise σ ≈ 7.7
    frames = laser + rng.poisson(ambient, laser.shape)
    dark_mean, dark_var = dark_statistics(rng.poisson(ambient, (10, 24, 24)), smooth=7)
    truth = s2(laser, 1).mean()
    plain = s2(frames, 1)
    corrected = ambient_corrected_s2(plain, frames.mean(axis=0), mean_square_difference(frames, 1),
                                     dark_mean, dark_var)
    assert plain.mean() / truth < 0.85  # ambient light lowers plain S2
    # 0.91: the level is corrected as a ratio of means, S2 is a mean of ratios (docs/ambient.md)
    assert corrected.mean() / truth == pytest.approx(0.95, abs=0.06)


def test_dark_pixels_read_zero_and_bad_dark_input_is_refused() -> None:
    frames = np.full((5, 2, 2), 10.0)
    frames[::2, 0, 0] = 14.0
    plain = s2(frames, 1)
    corrected = ambient_corrected_s2(plain, frames.mean(axis=0), mean_square_difference(frames, 1), 20.0, 1.0)
    assert (corrected == 0).all()  # the dark level exceeds the mean: no laser light to normalise by
    with pytest.raises(EstimatorError, match="dark_var"):
        ambient_corrected_s2(plain, frames.mean(axis=0), mean_square_difference(frames, 1), 1.0, -1.0)
    with pytest.raises(EstimatorError, match="dark_mean must be a scalar or a"):
        ambient_corrected_s2(plain, frames.mean(axis=0), mean_square_difference(frames, 1), np.zeros(3), 1.0)


@pytest.mark.slow
def test_bench_reproduces_the_defect_and_the_correction_removes_the_beam_imprint() -> None:
    result = measure(Case(size=64, frames=100, etas=(0.0, 0.2), lights=("gaussian",)))
    gt, amb = result.measures["gaussian"][0.0], result.measures["gaussian"][0.2]
    assert amb["S2 corrected"]["mean_ratio"] == pytest.approx(1.0, abs=0.25)
    assert amb["S2 plain"]["mean_ratio"] < 0.4
    assert amb["S2 plain"]["imprint"] > 0.4  # plain S2 shows the beam profile (§2B)
    assert amb["S2 dark-clipped"]["imprint"] < -0.1  # the old correction rises toward the dim edges
    assert abs(amb["S2 corrected"]["imprint"] - gt["S2 plain"]["imprint"]) < 0.15
    assert gt["S2 corrected"] == gt["S2 plain"]  # η = 0: the correction changes nothing
    assert 0.02 < result.clipped["gaussian"][0.2] < 0.1
    assert beats_plain(result)["gaussian"][0.0]


@pytest.mark.slow
def test_bench_ambient_quick_writes_the_table(tmp_path, capsys) -> None:
    out = tmp_path / "ambient.md"
    assert main(["bench", "ambient", "--quick", "--output", str(out)]) == 0
    text = out.read_text(encoding="utf-8")
    rows = [line for line in text.splitlines() if line.startswith(("| uniform |", "| gaussian |"))]
    assert len(rows) == 2 * 5 * 5  # lights x η x estimators
    gaussian_02 = {r.split("|")[3].strip(): r for r in rows if r.startswith("| gaussian | 0.2 |")}
    imprint = {name: float(row.split("|")[5]) for name, row in gaussian_02.items()}
    assert imprint["S2 plain"] > 0.4 and abs(imprint["S2 corrected"]) < 0.2
    assert "- gaussian: corrected S2 beats plain S2 on all four — η=0: yes" in text
    assert "64², N = 100" in text
    assert rows[0] in capsys.readouterr().out  # printed as well as written
