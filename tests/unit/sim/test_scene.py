from __future__ import annotations

import itertools

import pytest

from edgedsm.errors import ConfigError
from edgedsm.sim import load_scene, region_masks, scene_from_dict, tau_c_map
from edgedsm.sim.defaults import DEFAULT_SCENE, default_scene


def test_every_example_scene_loads(repo):
    files = sorted((repo / "config" / "scenes").glob("*.toml"))
    assert {f.stem for f in files} >= {"constant", "logos", "ring", "drying_plate"}
    for path in files:
        scene = load_scene(path)
        assert scene.scene.size >= 16


def test_builtin_default_is_the_logo_scene_file(repo):
    from_file = load_scene(repo / "config" / "scenes" / "logos.toml")
    assert from_file.model_dump() == default_scene().model_dump()


def test_logo_area_fraction_close_to_paper():
    # paper §2C: 29490 of 262144 object-grid points belong to the logos (11.2 %)
    masks = region_masks(default_scene())
    assert 0.09 < masks["regions"].mean() < 0.13
    tau = tau_c_map(default_scene())
    assert tau.shape == (512, 512)
    assert 0.09 < (tau == 10.0).mean() < 0.13


def test_unknown_key_is_refused_with_its_path():
    with pytest.raises(ConfigError, match=r"activity\.regionz: unknown key"):
        scene_from_dict({"activity": {"tau_c": 5, "regionz": []}})


def test_bad_region_value_names_the_nested_path():
    data = {"activity": {"tau_c": 5, "regions": [
        {"shape": "rect", "x": 0, "y": 0, "width": 5, "height": 5, "tau_c": 2},
        {"shape": "circle", "cx": 1, "cy": 1, "radius": 3, "tau_c": -1},
    ]}}
    with pytest.raises(ConfigError, match=r"activity\.regions\.1\.tau_c: Input should be greater than 0"):
        scene_from_dict(data)


def test_every_problem_is_listed():
    with pytest.raises(ConfigError) as info:
        scene_from_dict({"scene": {"size": 3, "colour": 1}, "activity": {"tau_c": 0}})
    message = str(info.value)
    assert "scene.size" in message and "scene.colour" in message and "activity.tau_c" in message


def test_ambient_light_needs_a_detector():
    with pytest.raises(ConfigError, match="ambient_light needs a"):
        scene_from_dict({"activity": {"tau_c": 5}, "ambient_light": {"eta": 0.2}})


def test_pupil_or_speckle_size_not_both():
    with pytest.raises(ConfigError, match=r"either speckle_size or pupil"):
        scene_from_dict({"scene": {"speckle_size": 2, "pupil": {"diameter_mm": 5, "focal_mm": 50}},
                         "activity": {"tau_c": 5}})


def test_pupil_gives_speckle_size():
    scene = scene_from_dict({"scene": {"pupil": {"diameter_mm": 3.168, "focal_mm": 50,
                                                 "wavelength_nm": 632.8, "pixel_pitch_um": 3.45}},
                             "activity": {"tau_c": 5}})
    # λf/(DΔ) = 632.8e-9 * 0.05 / (3.168e-3 * 3.45e-6)
    assert scene.scene.effective_speckle_size == pytest.approx(2.895, rel=1e-3)


def test_bad_toml_and_missing_file(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[scene\nsize = 3")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_scene(bad)
    with pytest.raises(ConfigError, match="file not found"):
        load_scene(tmp_path / "missing.toml")


def test_missing_mask_image_is_a_config_error(tmp_path):
    path = tmp_path / "scene.toml"
    path.write_text('[activity]\ntau_c = 5\n[[activity.regions]]\nshape = "mask"\npath = "nope.png"\ntau_c = 1\n')
    with pytest.raises(ConfigError, match=r"nope\.png"):
        tau_c_map(load_scene(path))


def test_mask_region_from_image(tmp_path):
    import cv2
    import numpy as np

    image = np.zeros((32, 32), np.uint8)
    image[8:16, 4:12] = 255
    cv2.imwrite(str(tmp_path / "mask.png"), image)
    path = tmp_path / "scene.toml"
    path.write_text('[scene]\nsize = 32\n[activity]\ntau_c = 5\n'
                    '[[activity.regions]]\nshape = "mask"\npath = "mask.png"\ntau_c = 1\n')
    tau = tau_c_map(load_scene(path), scale=1)
    assert (tau == 1).sum() == 64
    assert (tau[8:16, 4:12] == 1).all()


@pytest.mark.parametrize("law", ["exponential", "linear", "logistic"])
def test_drying_factor_runs_from_one_to_final(law):
    scene = scene_from_dict({"activity": {"tau_c": 5, "drying": {
        "law": law, "start": 10, "duration": 100, "final_factor": 50}}})
    drying = scene.activity.drying
    values = [drying.factor(i) for i in range(0, 130)]
    assert values[0] == 1.0 and values[10] == pytest.approx(1.0)
    assert values[110] == pytest.approx(50.0) and values[129] == pytest.approx(50.0)
    assert all(b >= a for a, b in itertools.pairwise(values))


def test_default_scene_dict_is_not_mutated():
    scene = default_scene()
    scene.scene.seed = 99
    assert DEFAULT_SCENE["scene"]["seed"] == 1
    assert default_scene().scene.seed == 1


def test_load_scene_takes_default_as_the_cli_does(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # not read from the repository: the built-in scene
    assert load_scene("default") == default_scene()
    with pytest.raises(ConfigError):
        load_scene("defaults")  # any other name is a file, and there is none
