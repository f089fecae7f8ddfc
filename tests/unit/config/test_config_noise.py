"""The noise settings of the daemon config: [camera.noise] (a datasheet), estimator.noise_floor,
noise_patch and intensity_change, bounded and shown by check-config (docs/noise.md, §5c)."""

from __future__ import annotations

import json

import pytest

from edgedsm.cli import main
from edgedsm.config import DaemonConfig
from edgedsm.validation import validate

CAMERA = "[camera]\nuri = 'sim:default'\n"


def test_the_noise_floor_is_on_by_default_and_a_datasheet_gives_the_model():
    plain = validate(DaemonConfig, {"camera": {"uri": "sim:default"}}, "<plain>")
    assert plain.estimator.noise_floor and plain.camera.noise is None
    assert (plain.estimator.noise_patch, plain.estimator.intensity_change) == (64, 3.0)
    sheet = validate(DaemonConfig, {"camera": {"uri": "sim:default", "noise": {"gain": 0.1, "dark_noise_e": 5.0,
                                                                                 "dark_mean": 2.0}}}, "<sheet>")
    model = sheet.camera.noise.model()
    assert (model.gain, model.dark_variance, model.dark_mean, model.source) == (0.1, pytest.approx(0.25), 2.0,
                                                                               "datasheet")


@pytest.mark.parametrize(("text", "key"), [
    ("[camera.noise]\ngain = 0\n", "camera.noise.gain"),
    ("[camera.noise]\ngain = 0.1\ncolour = 1\n", "camera.noise.colour"),
    ("[camera.noise]\ndark_noise_e = 3\n", "camera.noise.gain"),
    ("[estimator]\nnoise_patch = 8\n", "estimator.noise_patch"),
    ("[estimator]\nintensity_change = 1.0\n", "estimator.intensity_change"),
])
def test_bad_noise_settings_are_refused_with_their_key_path(tmp_path, capsys, text, key):
    camera, extra = (CAMERA.rstrip("\n") + "\n" + text, "") if text.startswith("[camera") else (CAMERA, text)
    path = tmp_path / "bad.toml"
    path.write_text(camera + extra)
    assert main(["check-config", str(path)]) == 78
    assert key in capsys.readouterr().err


def test_check_config_says_how_the_states_meet_the_noise(tmp_path, capsys):
    path = tmp_path / "c.toml"
    path.write_text(CAMERA + "[camera.noise]\ngain = 0.1\n")
    assert main(["check-config", str(path)]) == 0
    assert "noise floor: on, states judged above it; noise model from the [camera.noise] datasheet" in \
        capsys.readouterr().out
    path.write_text(CAMERA + "[estimator]\nnoise_floor = false\n")
    assert main(["check-config", "--json", str(path)]) == 0
    assert json.loads(capsys.readouterr().out)["noise_floor"] == {"on": False, "model": None, "patch_px": 64,
                                                                  "intensity_change": 3.0}


def test_a_new_datasheet_or_light_change_factor_is_applied_without_restarting_the_measurement():
    from edgedsm.daemon.reload import restart_reasons

    running = validate(DaemonConfig, {"camera": {"uri": "sim:default"}}, "<a>")
    sheet = validate(DaemonConfig, {"camera": {"uri": "sim:default", "noise": {"gain": 0.2}},
                                    "estimator": {"intensity_change": 5.0}}, "<b>")
    assert restart_reasons(sheet, running) == []
    patch = validate(DaemonConfig, {"camera": {"uri": "sim:default"}, "estimator": {"noise_patch": 32}}, "<c>")
    assert restart_reasons(patch, running) == ["estimator"]  # the patches are allocated with the engine
    moved = validate(DaemonConfig, {"camera": {"uri": "sim:default", "noise": {"gain": 0.2},
                                               "exposure_us": 100.0}}, "<d>")
    assert restart_reasons(moved, running) == ["camera"]
