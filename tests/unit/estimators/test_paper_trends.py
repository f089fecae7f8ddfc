"""The trends of the paper's §2 noise analysis, on small seeded simulations.

Margins were chosen from seeds 1-8 (96 px, N = 200, m = 10): each threshold sits at about
two thirds of the smallest effect seen over those seeds, so a weaker trend fails. GT and noisy
runs share their seed, hence their surface and activity streams: differences are paired.
"""

from __future__ import annotations

import functools
import json

import numpy as np
import pytest

from edgedsm.analysis import contrast
from edgedsm.errors import EdgedsmError
from edgedsm.estimators import all_maps
from edgedsm.sim import Simulator, region_masks, scene_from_dict

SIZE = 96
FRAMES = 200
LAG = 10
SEED = 3
_F = SIZE / 256


def _logo_scene(alpha: float = 0.0, tau_noise: float = 1.0, model: str = "white") -> dict:
    """Paper Figs. 3-7: "IOMT" and "ETRI" (τc = 10 Δt) on a τc = 50 Δt background, uniform light."""
    letters = [{"shape": "text", "text": text, "x": 48 * _F, "y": y * _F, "height": 62 * _F,
                "tau_c": 10.0} for text, y in (("IOMT", 45), ("ETRI", 150))]
    scene = {"scene": {"size": SIZE, "frames": FRAMES, "seed": SEED},
             "activity": {"tau_c": 50.0, "regions": letters},
             "detector": {"n_max": 1000, "bits": 8}}
    if alpha > 0:
        scene["phase_noise"] = {"alpha": alpha, "tau_noise": tau_noise, "model": model}
    return scene


@functools.cache
def _logo_betas(alpha: float = 0.0, tau_noise: float = 1.0, model: str = "white") -> dict[str, float]:
    """β = (S_l - S_b)/S_l of S1, S2, S3 for one logo simulation."""
    scene = scene_from_dict(_logo_scene(alpha, tau_noise, model))
    masks = region_masks(scene)
    frames = np.stack(list(Simulator(scene).frames()))
    return {name: contrast(values, masks["regions"], masks["background"])
            for name, values in all_maps(frames, LAG).items()}


def test_beta_of_s1_falls_as_alpha_rises() -> None:
    """Fig. 3: the map contrast worsens as the phase noise α grows (τ_noise = Δt)."""
    beta = {alpha: _logo_betas(alpha)["s1"] for alpha in (0.0, 0.2, 0.5)}
    # seeds 1-8: β(0) - β(0.2) = 0.059-0.064, β(0.2) - β(0.5) = 0.154-0.166
    assert beta[0.0] - beta[0.2] > 0.04, beta
    assert beta[0.2] - beta[0.5] > 0.10, beta
    assert beta[0.0] > 0.3, beta  # the ground-truth logos have a clear contrast (0.355-0.373)


@pytest.mark.parametrize("model", ["white", "ou"])
def test_beta_of_s1_rises_with_tau_noise_towards_ground_truth(model: str) -> None:
    """Fig. 5: slower (longer-correlated) phase noise harms the map less; β approaches GT."""
    short, long = _logo_betas(0.2, 1.0, model)["s1"], _logo_betas(0.2, 20.0, model)["s1"]
    truth = _logo_betas(0.0)["s1"]
    # seeds 1-8: β(τ=20) - β(τ=1) = 0.056-0.064; |β(τ=20) - β_GT| <= 0.005
    assert long - short > 0.04, (short, long)
    assert abs(long - truth) < 0.02, (long, truth)


def test_s3_has_lower_contrast_than_s1_and_s2() -> None:
    """Figs. 5-7: β of S1 and S2 is higher than β of S3 (here under the same uniform light)."""
    beta = _logo_betas(0.0)
    # seeds 1-8: β3/β1 = 0.50-0.56, β3/β2 = 0.67-0.71
    assert beta["s3"] < 0.65 * beta["s1"], beta
    assert beta["s3"] < 0.8 * beta["s2"], beta


def _edge_to_centre(values: np.ndarray) -> float:
    """Mean of a map in the image corners (r >= size/2) over its mean near the axis (r < size/4)."""
    coords = np.arange(values.shape[0]) + 0.25 - values.shape[0] / 2
    radius = np.hypot(coords[:, None], coords[None, :])
    return float(values[radius >= values.shape[0] / 2].mean() / values[radius < values.shape[0] / 4].mean())


def test_s3_is_insensitive_to_ambient_light_where_s2_is_not() -> None:
    """Fig. 2 / Fig. 4: ambient light lowers S2 and imprints the Gaussian beam on it; S3 holds."""
    maps = {}
    for eta in (0.0, 0.2):
        scene = {"scene": {"size": SIZE, "frames": FRAMES, "seed": SEED},
                 "activity": {"tau_c": 20.0},
                 "illumination": {"kind": "gaussian", "omega": 0.6 * SIZE},
                 "detector": {"n_max": 1000, "bits": 8}}
        if eta:
            scene["ambient_light"] = {"eta": eta}
        frames = np.stack(list(Simulator(scene_from_dict(scene)).frames()))
        maps[eta] = all_maps(frames, LAG)
    beam = np.exp(-((np.arange(SIZE) + 0.25 - SIZE / 2) / (0.6 * SIZE)) ** 2)
    assert _edge_to_centre(np.outer(beam, beam)) < 0.5  # the corners are well below half-lit

    s2_ratio = maps[0.2]["s2"].mean() / maps[0.0]["s2"].mean()
    s3_ratio = maps[0.2]["s3"].mean() / maps[0.0]["s3"].mean()
    # seeds 1-8: S2 x0.25-0.30, S3 x1.03-1.05
    assert s2_ratio < 0.5, s2_ratio
    assert 0.95 < s3_ratio < 1.10, s3_ratio

    # seeds 1-8: S2 edge/centre 1.02-1.05 (GT) -> 0.66-0.68; S3 1.00-1.02 -> 1.04-1.06
    s2_drop = _edge_to_centre(maps[0.0]["s2"]) - _edge_to_centre(maps[0.2]["s2"])
    s3_change = abs(_edge_to_centre(maps[0.0]["s3"]) - _edge_to_centre(maps[0.2]["s3"]))
    assert abs(_edge_to_centre(maps[0.0]["s2"]) - 1.0) < 0.1  # GT S2 is flat under the beam
    assert s2_drop > 0.2, s2_drop
    assert s3_change < 0.1, s3_change


@pytest.mark.slow
def test_reproduce_quick_writes_report_and_figures(tmp_path) -> None:
    """`reproduce(quick=True)` writes report.md with every section, its figures and results.json."""
    pytest.importorskip("matplotlib")
    from edgedsm_lab.report import reproduce

    calls: list[int] = []

    class Bar:
        def update(self, n: int = 1) -> None:
            calls.append(n)

        def close(self) -> None:
            calls.append(0)

    def progress(total: int) -> Bar:
        calls.append(-total)
        return Bar()

    report = reproduce(tmp_path / "out", size=64, frames=60, quick=True, progress=progress)
    assert report == tmp_path / "out" / "report.md"
    text = report.read_text(encoding="utf-8")
    for heading in ("## Fig. 2", "## Fig. 3", "## Fig. 4", "## Figs. 5-7",
                    "## What this confirms and what it does not", "edgedsm reproduce"):
        assert heading in text
    figures = ["fig2_histograms.png", "fig2_maps.png", "fig3_maps.png", "fig4_maps.png",
               "fig5_7_beta.png"]
    for name in figures:
        data = (report.parent / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000, name
        assert f"({name})" in text
    results = json.loads((report.parent / "results.json").read_text(encoding="utf-8"))
    assert results["settings"]["quick"] is True and results["settings"]["size"] == 64
    assert set(results["fig3"]["white"]) == {"0.0", "0.2", "0.5"}
    assert -calls[0] == results["optical_runs"] * 60  # total frames announced up front
    assert sum(n for n in calls[1:-1]) == -calls[0] and calls[-1] == 0  # every frame, then close
    assert text.count("— *") >= 10  # one verdict per finding


def test_reproduce_refuses_settings_it_cannot_run(tmp_path) -> None:
    from edgedsm_lab.report import reproduce

    with pytest.raises(EdgedsmError, match="frames"):
        reproduce(tmp_path, frames=15)
    with pytest.raises(EdgedsmError, match="size"):
        reproduce(tmp_path, size=16)
    assert not list(tmp_path.iterdir())


def test_reproduce_command_reports_bad_settings_cleanly(capsys) -> None:
    from edgedsm.cli import main

    assert main(["reproduce", "--frames", "5", "-o", "unused"]) == 1
    assert "frames must be >= 21" in capsys.readouterr().err
