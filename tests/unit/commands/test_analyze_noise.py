"""`analyze --json` reports the activity above the camera's noise (issue 23): on a simulated
film that darkens 10x while it dries, the raw S3 of the nearly dry film is half the wet film's,
but above the noise floor S1 and S2 fall by two orders of magnitude; a static surface reads 'low'
for every estimator."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from edgedsm.cli import main
from edgedsm.sim import load_scene, simulate

SCENE = Path(__file__).resolve().parents[3] / "config" / "scenes" / "darkening_film.toml"
#: The scene's camera as a datasheet would give it: K = 255 / (16,000 + √16,000) DN/e⁻ (8 bits over
#: n_max + its shot noise), dark current 20 e⁻ per frame: σ_d = √20 e⁻, offset 20·K DN.
DATASHEET = ("--noise-gain", "0.0158", "--dark-noise", "4.47", "--dark-mean", "0.316")


@pytest.fixture(scope="module")
def film(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The scene's wet start (frames 0-99) and its dry end (the last 100 frames), as .npy."""
    scene = load_scene(SCENE)
    frames = np.stack(list(simulate(scene)))
    folder = tmp_path_factory.mktemp("film")
    wet, dry = folder / "wet.npy", folder / "dry.npy"
    np.save(wet, frames[:100])
    np.save(dry, frames[-100:])
    return wet, dry


def _analyze(path: Path, estimator: str, tmp_path: Path, capsys: pytest.CaptureFixture[str], *extra: str) -> dict:
    assert main(["analyze", str(path), "--estimator", estimator, "--lag", "5", "-o", str(tmp_path / "m.npy"),
                 "--json", *extra]) == 0
    return json.loads(capsys.readouterr().out)


def test_above_the_noise_the_darkening_film_dries_though_raw_s3_stays_high(
        film: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    wet_path, dry_path = film
    raw = {name: _analyze(path, "s3", tmp_path, capsys, *DATASHEET) for name, path in (("wet", wet_path),
                                                                                       ("dry", dry_path))}
    assert raw["dry"]["mean"] > 0.4 * raw["wet"]["mean"]  # the reversal issue 23 describes
    assert raw["dry"]["above_noise"] < 0.5 * raw["wet"]["above_noise"]
    results = {(name, estimator): _analyze(path, estimator, tmp_path, capsys, *DATASHEET)
               for name, path in (("wet", wet_path), ("dry", dry_path)) for estimator in ("s1", "s2")}
    for estimator in ("s1", "s2"):
        wet, dry = results["wet", estimator], results["dry", estimator]
        assert wet["above_noise_verdict"] == "ok" and wet["noise_model"]["source"] == "datasheet"
        assert dry["noise_floor"] > dry["above_noise"]  # most of what the dry film shows is noise
    s1_wet, s1_dry = results["wet", "s1"], results["dry", "s1"]
    assert s1_dry["above_noise"] < 0.01 * s1_wet["above_noise"]
    s2_wet, s2_dry = results["wet", "s2"], results["dry", "s2"]
    assert s2_dry["mean"] > 0.15 * s2_wet["mean"]  # raw S2: the darkening keeps the dry film's value up
    assert s2_dry["above_noise"] < 0.06 * s2_wet["above_noise"]


def test_a_static_surface_is_low_for_every_estimator(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    scene = tmp_path / "static.toml"
    scene.write_text("[scene]\nsize = 64\nframes = 100\nseed = 3\nspeckle_size = 2.0\n\n[activity]\n"
                     "tau_c = 1000000.0\n\n[detector]\nn_max = 2000\nbits = 8\n", encoding="utf-8")
    frames = tmp_path / "static.npy"
    np.save(frames, np.stack(list(simulate(load_scene(scene)))))
    for estimator in ("s1", "s2", "s3"):
        result = _analyze(frames, estimator, tmp_path, capsys)
        assert result["noise_model"]["source"] == "frames"
        assert result["above_noise_verdict"] == "low" and result["signal"]["quality"] == "low", result
        assert abs(result["above_noise"]) <= 3 * result["above_noise_spread"], result


def test_fast_activity_without_a_datasheet_says_why_the_noise_is_unknown(
        film: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    wet_path, _ = film
    wet = _analyze(wet_path, "s1", tmp_path, capsys)
    assert wet["above_noise"] is None and "give the camera's noise" in wet["noise_model_error"]
    assert wet["signal"]["quality"] == "ok"
