from __future__ import annotations

import json

import pytest

from edgedsm.cli import main
from edgedsm.config import DaemonConfig, config_schema, load_config
from edgedsm.errors import ConfigError
from edgedsm.validation import validate


def test_demo_config_is_valid(repo):
    config = load_config(repo / "config" / "daemon" / "demo.toml")
    assert config.mqtt is not None and config.mqtt.device == "demo"  # the instance name is the topic name
    assert config.regions[0].thresholds().wet_above == 0.20  # S2 above the noise floor (docs/noise.md, §5c)


def test_example_config_only_lacks_the_plant_files(repo, tmp_path, capsys):
    # valid as shipped (TLS commented out); with its TLS lines uncommented only the CA file is missing
    text = (repo / "config" / "daemon" / "example.toml").read_text()
    assert "\n# [mqtt.tls]\n# ca_file = " in text
    tls = tmp_path / "tls.toml"
    tls.write_text(text.replace("\n# [mqtt.tls]\n# ca_file = ", "\n[mqtt.tls]\nca_file = "))
    assert main(["check-config", str(tls)]) == 78
    err = capsys.readouterr().err
    assert "mqtt.tls.ca_file: Path does not point to a file" in err
    assert len([line for line in err.splitlines() if ": " in line and "toml" in line]) == 1


def test_a_camera_is_all_a_config_needs():
    config = validate(DaemonConfig, {"camera": {"uri": "sim:default"}}, "<minimal>")
    assert config.camera.uri == "sim:default" and config.estimator.window == 200
    assert config.regions[0].name == "full"


@pytest.mark.parametrize(("text", "message"), [
    ("[camera]\nurl = 'x'", "camera.url: unknown key"),
    ("[estimator]\nwindow = 10\nlag = 10", "estimator: Value error, lag (10) must be smaller than window (10)"),
    ("[estimator]\nwindow = 1", "estimator.window: Input should be greater than or equal to 2"),
    ("[[regions]]\nname = 'a'\nwet_above = 1\ndry_below = 2", "regions.0: Value error, need 0 < dry_below"),
    ("[[regions]]\nname = 'a'\nshape = 'rect'\nwet_above = 2\ndry_below = 1", "regions.0.width: Field required"),
    ("[[regions]]\nname = 'a b'\nwet_above = 2\ndry_below = 1", "regions.0.name: String should match pattern"),
    ("[mqtt]\npassword = 'secret'", "EDGEDSM_MQTT_PASSWORD"),
    ("[acquisition]\nmode = 'sometimes'", "acquisition.mode: Input should be 'continuous' or 'bursts'"),
])
def test_bad_config_names_key_path_and_exits_78(tmp_path, capsys, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=r"bad\.toml"):
        load_config(path)
    assert main(["check-config", str(path)]) == 78
    assert message in capsys.readouterr().err


def test_run_refuses_a_bad_config_with_78(tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_text("[estimator]\nlag = 0\n")
    assert main(["run", "-c", str(path)]) == 78
    assert "estimator.lag" in capsys.readouterr().err


def test_schema_for_editors(capsys):
    assert main(["check-config", "--schema"]) == 0
    schema = json.loads(capsys.readouterr().out)
    assert schema == config_schema()
    props = schema["properties"]
    assert {"camera", "laser", "estimator", "regions", "mqtt", "acquisition"} <= set(props)
    assert schema["additionalProperties"] is False


def test_region_masks(tmp_path):
    text = """
[camera]
uri = "sim:default"
[[regions]]
name = "box"
shape = "rect"
x = 2
y = 1
width = 3
height = 2
wet_above = 2
dry_below = 1
[[regions]]
name = "tri"
shape = "polygon"
points = [[0, 0], [7, 0], [0, 7]]
wet_above = 2
dry_below = 1
[[regions]]
name = "outside"
shape = "circle"
cx = 100
cy = 100
radius = 2
wet_above = 2
dry_below = 1
"""
    path = tmp_path / "c.toml"
    path.write_text(text)
    config = load_config(path)
    box = config.regions[0].mask((8, 8), tmp_path)
    assert box.sum() == 6 and box[1:3, 2:5].all()
    assert 20 < config.regions[1].mask((8, 8), tmp_path).sum() < 40
    with pytest.raises(ConfigError, match=r"regions\.outside: the region has no pixel"):
        config.regions[2].mask((8, 8), tmp_path)


def test_missing_mask_image_is_refused_at_load(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("[camera]\nuri = 'sim:'\n"
                    "[[regions]]\nname = 'm'\nshape = 'mask'\npath = 'nope.png'\nwet_above = 2\ndry_below = 1\n")
    with pytest.raises(ConfigError, match=r"regions\.0\.path: .*nope\.png cannot be read as an image"):
        load_config(path)
