"""The ``[mqtt]`` table of the daemon config: broker, identity, TLS, cadence, map encoding.

The password is deliberately NOT a field: a config file is often world-readable, copied into
tickets and checked into version control. It comes from the environment variable
``EDGEDSM_MQTT_PASSWORD`` or from the systemd credential file ``$CREDENTIALS_DIRECTORY/mqtt-password``
(``LoadCredential=mqtt-password:/etc/edgedsm/mqtt-password`` in the unit); see
:func:`resolve_password`.
"""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, Field, FilePath, field_validator, model_validator

from edgedsm.errors import ConfigError
from edgedsm.publish.command_auth import KeyFileError, parse_keys
from edgedsm.validation import StrictModel

PASSWORD_ENV = "EDGEDSM_MQTT_PASSWORD"
CREDENTIAL_NAME = "mqtt-password"
COMMAND_KEY_ENV = "EDGEDSM_COMMAND_KEY"
COMMAND_KEY_CREDENTIAL = "command-key"

# A topic level: no MQTT wildcards, no NUL, no empty levels (they confuse subscribers).
_TOPIC_PREFIX = r"^[^#+/\x00\s]+(/[^#+/\x00\s]+)*$"
TOPIC_PREFIX_PATTERN = _TOPIC_PREFIX  # for other topic-prefix fields (e.g. [homeassistant])


def _not_the_brokers(value: str) -> str:
    """A topic starting with '$' is the broker's ($SYS/...): publishes there are dropped."""
    if value.startswith("$"):
        raise ValueError("must not start with '$': topics beginning with '$' belong to the broker ($SYS), "
                         "which drops what clients publish there (every state and alert would be lost)")
    return value


#: A topic prefix: one or more levels, no wildcards, NUL, spaces or empty levels, not the broker's '$'.
TopicPrefix = Annotated[str, Field(min_length=1, max_length=128, pattern=_TOPIC_PREFIX),
                        AfterValidator(_not_the_brokers)]

_DEVICE = r"^[A-Za-z0-9_.-]{1,64}$"
#: The one default device name: ``[device] name``, ``[mqtt] device`` and ``edgedsm watch`` agree.
DEFAULT_DEVICE = "camera1"


#: Keys a daemon config once had in ``[mqtt]`` and now has in ``[cadence]`` (the pipeline's, for
#: every sink): still accepted in ``[mqtt]``, moved there with a deprecation note.
CADENCE_KEYS = ("stats_interval_s", "maps_interval_s")


class MqttTlsSettings(StrictModel):
    """``[mqtt.tls]``: present = TLS on. Without ``ca_file`` the system's CA store is used."""

    ca_file: FilePath | None = Field(
        None, description="PEM file of the CA(s) that signed the broker's certificate; "
                          "absent: the system's trusted CAs")
    cert_file: FilePath | None = Field(
        None, description="PEM client certificate, for brokers that require one (require_certificate)")
    key_file: FilePath | None = Field(
        None, description="PEM private key of the client certificate (unencrypted; protect it with "
                          "file permissions or LoadCredential)")
    insecure: bool = Field(
        False, description="skip the check that the broker's certificate names the host we connect to "
                           "(the chain is still verified); for brokers reached by IP. Off by default")

    @model_validator(mode="after")
    def _cert_and_key_together(self) -> MqttTlsSettings:
        if (self.cert_file is None) != (self.key_file is None):
            raise ValueError("cert_file and key_file go together: give both or neither")
        return self


class MqttSettings(StrictModel):
    """Connection to the MQTT broker and what is published how often.

    Topics are ``<topic_prefix>/<device>/...`` (see ``edgedsm.publish.mqtt.Topics``).
    """

    host: str = Field("localhost", min_length=1, max_length=253,
                      description="broker host name or IP address")
    port: int = Field(1883, ge=1, le=65535,
                      description="broker TCP port (1883 plain, 8883 usual for TLS)")
    client_id: str | None = Field(
        None, min_length=1, max_length=128, pattern=r"^[\x21-\x7e]+$",
        description="MQTT client id; default '<topic_prefix>-<device>' with '/' replaced by '-'. "
                    "Must be unique on the broker: a second client with the same id throws the first off")
    topic_prefix: TopicPrefix = Field("edgedsm",
                                      description="first topic level(s), e.g. 'plant1/edgedsm'; no wildcards")
    device: str = Field(DEFAULT_DEVICE, pattern=_DEVICE,
                        description="this camera's name in the topics (letters, digits, '_', '.', '-')")
    protocol: Literal["3.1.1", "5"] = Field(
        "5", description="MQTT protocol version; '5' also sees a retained command as retained when it is "
                         "first delivered (and refuses it) and echoes a command's correlation data")
    keepalive_s: int = Field(30, ge=5, le=3600,
                             description="keepalive in seconds; the broker sends the last will "
                                         "('offline') after about 1.5 times this without traffic")
    connect_timeout_s: float = Field(5.0, ge=0.5, le=60.0,
                                     description="TCP/TLS connect timeout in seconds")
    tls: MqttTlsSettings | None = Field(None, description="TLS; absent = plain TCP")
    username: str | None = Field(
        None, min_length=1, max_length=256,
        description="user name; its password comes from the environment variable "
                    f"{PASSWORD_ENV} or the credential file $CREDENTIALS_DIRECTORY/{CREDENTIAL_NAME}, "
                    "never from this file")
    reconnect_min_s: float = Field(1.0, ge=0.05, le=60.0,
                                   description="first wait before reconnecting after a lost connection")
    reconnect_max_s: float = Field(60.0, ge=0.1, le=3600.0,
                                   description="longest wait between reconnection attempts "
                                               "(the wait doubles from reconnect_min_s up to this)")
    alert_queue_max: int = Field(
        10_000, ge=10, le=1_000_000,
        description="alerts kept in the durable queue while the broker does not acknowledge them; "
                    "beyond this the oldest are dropped (counted and logged)")
    alerts_in_flight: int = Field(10, ge=1, le=20,
                                  description="alerts sent but not yet acknowledged at any one time")
    laser_command: bool = Field(
        True, description="accept cmd/laser (on/off/auto); false = refused, saying so, for sites whose laser-safety "
                          "sign-off does not cover switching the laser remotely (docs/laser-safety.md)")
    command_key_file: Path | None = Field(
        None, description="file of command keys ('KEY_ID SECRET' per line, docs/security.md); absent: "
                          f"${COMMAND_KEY_ENV}, else the systemd credential "
                          f"$CREDENTIALS_DIRECTORY/{COMMAND_KEY_CREDENTIAL}; no key at all: commands that "
                          "change the laser or the measurement are refused (read-only)")
    command_max_age_s: float = Field(
        30.0, ge=2.0, le=600.0,
        description="a signed command is refused when its 'issued' time is further than this from the "
                    "daemon's clock, either way; also how long its nonce is remembered against replays")
    map_max_size: int = Field(512, ge=8, le=8192,
                              description="longest side in pixels of a published map; larger maps are "
                                          "downsampled by area averaging (stated in the map's meta)")
    map_png_compression: int = Field(3, ge=0, le=9,
                                     description="zlib level of the map PNGs: 0 fastest, 9 smallest "
                                                 "(lossless either way)")
    shutdown_timeout_s: float = Field(1.0, ge=0.0, le=30.0,
                                      description="longest wait at shutdown for 'offline' to be "
                                                  "acknowledged before disconnecting")

    @model_validator(mode="before")
    @classmethod
    def _no_password_in_file(cls, data: Any) -> Any:
        # A clearer message than "unknown key": say where the password belongs.
        if isinstance(data, Mapping) and "password" in data:
            raise ValueError(
                f"'password' is not read from the config file: set the environment variable "
                f"{PASSWORD_ENV} or provide the systemd credential '{CREDENTIAL_NAME}' "
                f"(LoadCredential={CREDENTIAL_NAME}:/path/to/file)")
        return data

    @field_validator("host")
    @classmethod
    def _no_scheme(cls, value: str) -> str:
        if "://" in value or re.search(r"\s", value):
            raise ValueError("give a bare host name or IP address (no 'mqtt://', no spaces)")
        return value

    @model_validator(mode="after")
    def _backoff_order(self) -> MqttSettings:
        if self.reconnect_max_s < self.reconnect_min_s:
            raise ValueError("reconnect_max_s must be at least reconnect_min_s")
        return self

    @property
    def effective_client_id(self) -> str:
        """The client id used: the configured one, or '<prefix>-<device>'."""
        return self.client_id or f"{self.topic_prefix}-{self.device}".replace("/", "-")


def resolve_password(environ: Mapping[str, str] | None = None) -> str | None:
    """The broker password from ``$EDGEDSM_MQTT_PASSWORD`` or ``$CREDENTIALS_DIRECTORY/mqtt-password``.

    The environment wins when both are set. A trailing newline in the credential file is
    removed (editors add one). Returns None when neither is present; raises ConfigError when
    the credential file exists but cannot be read.
    """
    env = os.environ if environ is None else environ
    value = env.get(PASSWORD_ENV)
    if value:
        return value
    directory = env.get("CREDENTIALS_DIRECTORY")
    if not directory:
        return None
    path = Path(directory) / CREDENTIAL_NAME
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: MQTT password credential cannot be read: {exc}") from None
    return text.rstrip("\r\n") or None



def resolve_command_keys(settings: MqttSettings | None = None,
                         environ: Mapping[str, str] | None = None) -> dict[str, bytes]:
    """Command keys (key id -> secret, :mod:`edgedsm.publish.command_auth`) from
    ``$EDGEDSM_COMMAND_KEY`` (the key file's text), else ``[mqtt] command_key_file``, else
    ``$CREDENTIALS_DIRECTORY/command-key``. Empty when none is present or the credential is
    empty (read-only); ConfigError naming the source when one is unreadable or malformed."""
    env = os.environ if environ is None else environ
    text = env.get(COMMAND_KEY_ENV)
    if text:
        return _keys(text, f"${COMMAND_KEY_ENV}")
    if settings is not None and settings.command_key_file is not None:
        path, source = settings.command_key_file, f"mqtt.command_key_file: {settings.command_key_file}"
        missing_ok = False
    else:
        directory = env.get("CREDENTIALS_DIRECTORY")
        if not directory:
            return {}
        path = Path(directory) / COMMAND_KEY_CREDENTIAL
        source, missing_ok = f"{path} (systemd credential {COMMAND_KEY_CREDENTIAL})", True
    try:
        with path.open("rb") as file:
            data = file.read(64 * 1024 + 1)
    except FileNotFoundError:
        if missing_ok:
            return {}
        raise ConfigError(f"{source}: no such file") from None
    except OSError as exc:
        raise ConfigError(f"{source}: command key cannot be read: {exc.strerror or exc}") from None
    if len(data) > 64 * 1024:
        raise ConfigError(f"{source}: larger than 64 KiB, not a key file")
    try:
        return _keys(data.decode("utf-8"), source, empty_ok=missing_ok)
    except UnicodeDecodeError:
        raise ConfigError(f"{source}: not UTF-8 text") from None


def _keys(text: str, source: str, *, empty_ok: bool = False) -> dict[str, bytes]:
    """``empty_ok``: the credential, which the unit needs to exist (LoadCredential=), may be left
    empty for no key; a key file named in the config must hold one."""
    try:
        keys = parse_keys(text)
    except KeyFileError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    if not keys and not empty_ok:
        raise ConfigError(f"{source}: holds no key")
    return keys
