"""The device tables of a daemon config: ``[device]``, ``[camera]``, ``[laser]``, ``[acquisition]``.
The camera and relay URIs are parsed here, once (``camera.spec``, ``laser.spec``)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Literal

from pydantic import Field, PrivateAttr, field_validator

from edgedsm.devices.camera.uri import CameraSpec, parse_camera_uri, resolve_camera_spec
from edgedsm.devices.uri import RelaySpec, parse_relay_uri
from edgedsm.errors import ConfigError
from edgedsm.estimators.noise import NoiseModel, from_datasheet
from edgedsm.publish.settings import DEFAULT_DEVICE
from edgedsm.validation import StrictModel


class DeviceSection(StrictModel):
    name: str = Field(DEFAULT_DEVICE, min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$",
                      description="instance name; the MQTT topics are <prefix>/<name>/...")
    state_dir: Path = Field(default_factory=lambda: Path(os.environ.get("STATE_DIRECTORY", "/var/lib/edgedsm")),
                            description="durable state (alert queue); default: systemd's $STATE_DIRECTORY")
    commissioning_dir: Path | None = Field(
        None, description="where `edgedsm tune -c` this file keeps its last commissioning report and the dashboard "
                          "reads it (relative: to this file's folder); default <state_dir>/commissioning")

    def commissioning_directory(self, base_dir: Path) -> Path:
        """The last commissioning report's folder (docs/commissioning.md): ``commissioning_dir``
        resolved against ``base_dir`` (the config file's folder), else ``state_dir/commissioning``."""
        if self.commissioning_dir is None:
            return self.state_dir / "commissioning"
        return self.commissioning_dir if self.commissioning_dir.is_absolute() else base_dir / self.commissioning_dir


class CameraNoiseSection(StrictModel):
    """The camera's temporal noise from its EMVA 1288 datasheet (docs/noise.md); without it the
    daemon estimates the model from the frames."""

    gain: float = Field(gt=0, le=1000, description="system gain K in DN per electron (at the pixel format used)")
    dark_noise_e: float = Field(0.0, ge=0, le=10_000, description="dark noise σ_d in electrons")
    dark_mean: float = Field(0.0, ge=0, le=65_535, description="dark offset μ_dark in grey levels")

    def model(self) -> NoiseModel:
        return from_datasheet(self.gain, self.dark_noise_e, self.dark_mean)


class CameraSection(StrictModel):
    uri: str = Field(min_length=1, max_length=1024,
                     description="camera URI: aravis:ID, v4l2:/dev/videoN, replay:PATH, sim:SCENE.toml "
                                 "(required: a production config names its camera; sim:default is for demos)")
    exposure_us: float | None = Field(None, gt=0, le=60e6, description="exposure time in µs (camera default if unset)")
    frame_interval_s: float | None = Field(None, gt=0, le=3600,
                                           description="frame interval Δt in s (camera default if unset)")
    pixel_format: str | None = Field(None, max_length=32, description="Mono8, Mono10, Mono12, Mono12Packed, Mono16")
    grab_timeout_s: float = Field(5.0, gt=0, le=600, description="a frame not arriving within this is a fault")
    reconnect_initial_s: float = Field(0.5, gt=0, le=600, description="first reconnection delay after a loss")
    reconnect_max_s: float = Field(30.0, gt=0, le=3600, description="longest reconnection delay (backoff cap)")
    noise: CameraNoiseSection | None = Field(None, description="the camera's noise from its datasheet (default: "
                                                               "estimated from the frames)")

    _base_dir: Path = PrivateAttr(default_factory=lambda: Path("."))
    _spec: CameraSpec | None = PrivateAttr(None)

    @field_validator("uri")
    @classmethod
    def _camera_uri_parses(cls, value: str) -> str:
        # a typo in the URI must be refused here (check-config, run, SIGHUP), not when opening
        try:
            parse_camera_uri(value)
        except ConfigError as exc:
            raise ValueError(str(exc)) from None
        return value

    @field_validator("pixel_format")
    @classmethod
    def _known_pixel_format(cls, value: str | None) -> str | None:
        # the formats a camera accepts (Camera.set_pixel_format): refused here, not by the start (exit 69)
        from edgedsm.devices.camera.base import PIXEL_FORMATS

        if value is not None and value not in PIXEL_FORMATS:
            raise ValueError(f"{value!r} is not a pixel format edgedsm measures with: use one of "
                             f"{', '.join(sorted(PIXEL_FORMATS))}")
        return value

    @property
    def spec(self) -> CameraSpec:
        """The parsed camera URI, relative paths resolved against the config file's directory and
        a sim: scene read (once: ``load_config`` does it, so that a missing file is a config error)."""
        if self._spec is None or self._spec.uri != self.uri.strip():
            self._spec = resolve_camera_spec(parse_camera_uri(self.uri), self._base_dir)
        return self._spec

    def resolve(self, base_dir: Path) -> CameraSpec:
        """Resolve the spec against ``base_dir`` now; ConfigError says what is wrong."""
        self._base_dir, self._spec = base_dir, None
        return self.spec


class LaserSection(StrictModel):
    uri: str = Field(min_length=1, max_length=1024,
                     description="relay URI, e.g. serial:/dev/ttyUSB0?protocol=lcus&channel=1 or sim:")

    _spec: RelaySpec | None = PrivateAttr(None)

    @field_validator("uri")
    @classmethod
    def _relay_uri_parses(cls, value: str) -> str:
        try:
            parse_relay_uri(value)
        except ConfigError as exc:
            raise ValueError(str(exc)) from None
        return value

    @property
    def spec(self) -> RelaySpec:
        """The parsed relay URI (parsed once)."""
        if self._spec is None or self._spec.uri != self.uri.strip():
            self._spec = parse_relay_uri(self.uri)
        return self._spec


class AcquisitionSection(StrictModel):
    mode: Literal["continuous", "bursts"] = Field(
        "continuous", description="continuous: laser on while measuring; bursts: spare the laser")
    burst_frames: int = Field(400, ge=3, le=1_000_000, description="frames per burst (bursts mode)")
    burst_period_s: float = Field(600.0, gt=0, le=86400, description="start-to-start period of bursts")
    dark_frames: int = Field(10, ge=0, le=10_000, description="laser-off frames for the ambient level (0 = none)")
    dark_every_min: float = Field(30.0, ge=0, le=10080,
                                  description="repeat the dark frames every K minutes (0 = only at start)")
    queue_seconds: float = Field(1.0, gt=0, le=60, description="queue camera→estimator sized to hold this many "
                                 "seconds of frames at the measured rate (oldest dropped when full)")
    queue_max_mib: int = Field(512, ge=1, le=1_048_576, description="memory bound of that queue (MiB)")
    queue_frames: int | None = Field(None, ge=1, le=10_000,
                                     description="fixed queue length in frames instead (overrides queue_seconds)")
