"""The [mqtt] settings and the command models: validation only, no broker needed."""

from __future__ import annotations

import pytest
from pydantic import BaseModel

from edgedsm.errors import ConfigError
from edgedsm.publish import COMMANDS, LaserCommand, MqttSettings, MqttTlsSettings, Topics, resolve_password
from edgedsm.publish.settings import resolve_command_keys
from edgedsm.validation import validate


def test_defaults_and_derived_client_id():
    settings = MqttSettings()
    assert (settings.host, settings.port, settings.topic_prefix) == ("localhost", 1883, "edgedsm")
    assert settings.effective_client_id == "edgedsm-camera1"
    assert MqttSettings(topic_prefix="plant/a", device="line3").effective_client_id == "plant-a-line3"
    assert MqttSettings(client_id="x1").effective_client_id == "x1"


def test_password_in_the_file_is_refused_with_directions():
    with pytest.raises(ConfigError, match="EDGEDSM_MQTT_PASSWORD") as error:
        validate(MqttSettings, {"host": "b", "password": "secret"}, "line3.toml: mqtt")
    assert "secret" not in str(error.value)


@pytest.mark.parametrize(("data", "where"), [
    ({"hots": "b"}, "hots: unknown key"),
    ({"port": 0}, "port"),
    ({"port": 70000}, "port"),
    ({"topic_prefix": "a/#"}, "topic_prefix"),
    ({"topic_prefix": "a//b"}, "topic_prefix"),
    ({"topic_prefix": "$SYS"}, "topic_prefix: Value error, must not start with '$'"),
    ({"topic_prefix": "$share/plant"}, "topic_prefix: Value error, must not start with '$'"),
    ({"topic_prefix": "plant/+"}, "topic_prefix"),
    ({"topic_prefix": "plant\x00"}, "topic_prefix"),
    ({"device": "line 3"}, "device"),
    ({"host": "mqtt://broker"}, "host"),
    ({"keepalive_s": 1}, "keepalive_s"),
    ({"reconnect_min_s": 10, "reconnect_max_s": 5}, "reconnect_max_s must be at least"),
    ({"alert_queue_max": 1}, "alert_queue_max"),
    ({"tls": {"cert_file": "/etc/hostname"}}, "cert_file and key_file go together"),
    ({"tls": {"ca_file": "/nonexistent/ca.pem"}}, "tls.ca_file"),
    ({"tls": {"verify": False}}, "tls.verify: unknown key"),
])
def test_bad_values_are_refused_with_their_key_path(data, where):
    with pytest.raises(ConfigError, match="mqtt") as error:
        validate(MqttSettings, data, "cfg.toml: mqtt")
    assert where in str(error.value)


def _fields(model: type[BaseModel]):
    for name, field in model.model_fields.items():
        yield f"{model.__name__}.{name}", field


@pytest.mark.parametrize(("name", "field"), [*_fields(MqttSettings), *_fields(MqttTlsSettings)])
def test_every_field_is_described(name, field):
    assert field.description and len(field.description) > 10, name


def test_numeric_fields_are_bounded():
    for name, field in MqttSettings.model_fields.items():
        if field.annotation in (int, float):
            kinds = {type(item).__name__ for item in field.metadata}
            assert kinds & {"Ge", "Gt"} and kinds & {"Le", "Lt"}, name


def test_password_from_environment_then_credentials(tmp_path):
    assert resolve_password({}) is None
    assert resolve_password({"EDGEDSM_MQTT_PASSWORD": "env"}) == "env"
    (tmp_path / "mqtt-password").write_text("from-credential\n")
    creds = {"CREDENTIALS_DIRECTORY": str(tmp_path)}
    assert resolve_password(creds) == "from-credential"
    assert resolve_password({**creds, "EDGEDSM_MQTT_PASSWORD": "env"}) == "env"
    assert resolve_password({"CREDENTIALS_DIRECTORY": str(tmp_path / "none")}) is None


def test_unreadable_credential_is_a_config_error(tmp_path):
    (tmp_path / "mqtt-password").mkdir()  # a directory cannot be read as a file
    with pytest.raises(ConfigError, match="mqtt-password"):
        resolve_password({"CREDENTIALS_DIRECTORY": str(tmp_path)})


ALICE = "alice " + "a" * 64


def test_command_keys_from_environment_then_config_file_then_credential(tmp_path):
    assert resolve_command_keys(None, {}) == {}
    (tmp_path / "command-key").write_text("c" * 64 + "\n")
    creds = {"CREDENTIALS_DIRECTORY": str(tmp_path)}
    assert resolve_command_keys(None, creds) == {"default": b"c" * 64}
    named = tmp_path / "keys"
    named.write_text(f"# operators\n{ALICE}\nbob {'b' * 40}\n")
    settings = MqttSettings(command_key_file=named)
    assert resolve_command_keys(settings, creds) == {"alice": b"a" * 64, "bob": b"b" * 40}
    assert resolve_command_keys(settings, {**creds, "EDGEDSM_COMMAND_KEY": "e" * 32}) == {"default": b"e" * 32}
    assert resolve_command_keys(None, {"CREDENTIALS_DIRECTORY": str(tmp_path / "none")}) == {}
    (tmp_path / "command-key").write_text("")  # LoadCredential= needs the file: empty = no key
    assert resolve_command_keys(None, creds) == {}


@pytest.mark.parametrize(("content", "why"), [
    (None, "mqtt.command_key_file: .*: no such file"),
    ("short\n", "mqtt.command_key_file: .*: line 1: the secret of 'default' must be 32-1024"),
    ("# nothing but a comment\n", "mqtt.command_key_file: .*: holds no key"),
    (b"\xff" * 40, "mqtt.command_key_file: .*: not UTF-8"),
    ("x" * 70_000, "mqtt.command_key_file: .*: larger than 64 KiB"),
])
def test_a_bad_key_file_is_a_config_error_naming_the_key(tmp_path, content, why):
    path = tmp_path / "keys"
    if isinstance(content, bytes):
        path.write_bytes(content)
    elif content is not None:
        path.write_text(content)
    with pytest.raises(ConfigError, match=why):
        resolve_command_keys(MqttSettings(command_key_file=path), {})


def test_a_bad_key_in_the_environment_or_credential_names_it(tmp_path):
    with pytest.raises(ConfigError, match=r"\$EDGEDSM_COMMAND_KEY: line 1"):
        resolve_command_keys(None, {"EDGEDSM_COMMAND_KEY": "too short"})
    (tmp_path / "command-key").mkdir()
    with pytest.raises(ConfigError, match=r"systemd credential command-key.*cannot be read"):
        resolve_command_keys(None, {"CREDENTIALS_DIRECTORY": str(tmp_path)})


def test_topics():
    topics = Topics.of("plant/edgedsm", "line3")
    assert topics.availability == "plant/edgedsm/line3/availability"
    assert topics.map_meta("s2") == "plant/edgedsm/line3/map/s2/meta"
    assert topics.command_filter == "plant/edgedsm/line3/cmd/+"
    assert topics.reply("laser") == "plant/edgedsm/line3/cmd/laser/reply"


def test_command_models_are_strict():
    assert set(COMMANDS) == {"laser", "rebaseline", "dark", "publish_maps", "record"}
    assert LaserCommand.model_validate({"state": "on"}).state == "on"
    for bad in ({"state": "maybe"}, {}, {"state": "on", "power": 3}):
        with pytest.raises(ValueError, match=r"state|power"):
            LaserCommand.model_validate(bad)
    with pytest.raises(ValueError, match="extra"):
        COMMANDS["dark"].model_validate({"frames": 3})
    assert COMMANDS["record"].model_validate({}).seconds is None
    assert COMMANDS["record"].model_validate({"seconds": 2.5}).seconds == 2.5
    for bad in ({"seconds": 0}, {"seconds": 7200}, {"seconds": "long"}, {"frames": 3}):
        with pytest.raises(ValueError):
            COMMANDS["record"].model_validate(bad)


def test_a_dollar_inside_the_prefix_is_an_ordinary_character():
    # only a first level starting with '$' is the broker's (MQTT 3.1.1 §4.7.2)
    assert MqttSettings(topic_prefix="plant/$line").topic_prefix == "plant/$line"
