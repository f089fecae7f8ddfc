"""Daemon configuration (TOML), validated with pydantic: unknown keys refused, every field
bounded and described, types strict. ``edgedsm check-config FILE`` prints every problem with its
key path and exits 78; ``edgedsm check-config --schema`` prints the JSON Schema for editors.
The camera and relay URIs are parsed here, once (``config.camera.spec``, ``config.laser.spec``).
See docs/configuration.md.

Secrets never live in this file: the MQTT password comes from the environment or from
``$CREDENTIALS_DIRECTORY`` (see ``[mqtt]``).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import ConfigDict, Discriminator, Field, PrivateAttr, Tag, field_validator, model_validator
from pydantic_core.core_schema import ValidationInfo

from edgedsm import geometry
from edgedsm.devices.camera.uri import CameraSpec, parse_camera_uri, resolve_camera_spec
from edgedsm.devices.uri import RelaySpec, parse_relay_uri
from edgedsm.drying import Thresholds
from edgedsm.errors import ConfigError
from edgedsm.estimators.correlation_time import TAU_FLOOR, tau_mode_problem
from edgedsm.publish.settings import CADENCE_KEYS, DEFAULT_DEVICE, TOPIC_PREFIX_PATTERN, MqttSettings
from edgedsm.publish.sparkplug.settings import SparkplugSettings
from edgedsm.validation import StrictModel, read_toml, validate


class DeviceSection(StrictModel):
    name: str = Field(DEFAULT_DEVICE, min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$",
                      description="instance name; the MQTT topics are <prefix>/<name>/...")
    state_dir: Path = Field(default_factory=lambda: Path(os.environ.get("STATE_DIRECTORY", "/var/lib/edgedsm")),
                            description="durable state (alert queue); default: systemd's $STATE_DIRECTORY")


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


#: estimator.max_lag K when not given: twice the lag m, at most N - 2 (the engine's default).
def default_max_lag(window: int, lag: int) -> int:
    return max(1, min(2 * lag, window - 2))


class EstimatorSection(StrictModel):
    activity: Literal["s1", "s2", "s3", "tau_c"] = Field(
        "s2", description="estimator the drying states are judged on (S3 saturates once τc >> N; tau_c: the "
                          "region's correlation time in seconds, thresholds wet_below_s / dry_above_s)")
    window: int = Field(200, ge=2, le=100_000, description="N: frames per map (paper: 200)")
    lag: int = Field(10, ge=1, le=99_999, description="m: time lag in frames (paper: 10)")
    q: float = Field(1.0, ge=0, le=1e9, description="S2 regulariser q in grey levels (avoids 0/0)")
    mode: Literal["sliding", "exponential", "tumbling"] = Field("sliding", description="window mode of the engine")
    tau_c: bool = Field(
        False, description="also estimate the correlation time τc (docs/tau_c.md): a push of S1+S2+S3+τc "
                           "costs about 1.6-2.0x one of S1+S2+S3 at 2048², so off unless asked for here or "
                           "needed (activity = 'tau_c', or a region with wet_below_s / dry_above_s); needs mode "
                           "'sliding' or 'tumbling'")
    max_lag: int | None = Field(None, ge=1, le=99_998,
                                description="K: the longest lag in frames that τc is fitted over, at multi-tau lags "
                                            "1, 2, 3, 4, 6, 8, … K (default min(2·lag, window-2)); τc is measured up "
                                            "to K·Δt, above it reported as '> K·Δt'")
    tau_c_map: bool = Field(True, description="publish the τc map (seconds) with the other maps")
    tau_c_map_block: int | None = Field(
        None, ge=1, le=256, description="side b of the b×b pixel blocks the τc map is fitted over, pooled as a "
                                        "region (1: per pixel, ~6 µs each on the evaluator thread per map); "
                                        "default: the smallest b that keeps the map at 65,536 fits (2048²: 8)")
    ambient_correction: bool = Field(
        False, description="subtract the measured dark level from every frame before all estimators (off: the "
                           "validation in docs/ambient.md shows it distorts S2; use S3 under ambient light)")
    threads: int | None = Field(None, ge=1, le=256, description="kernel threads (default: all cores)")
    area: Literal["frame", "regions"] = Field(
        "frame", description="frame: maps of the whole sensor; regions: only the bounding box of all regions "
                             "(the cost follows the regions; the published maps cover that box)")

    @model_validator(mode="after")
    def _lag_fits(self) -> EstimatorSection:
        if self.lag >= self.window:
            raise ValueError(f"lag ({self.lag}) must be smaller than window ({self.window})")
        cores = os.cpu_count() or 1
        if self.threads is not None and self.threads > cores:
            raise ValueError(f"threads ({self.threads}) is more than this machine's {cores} cores")
        if self.max_lag is not None and self.max_lag > self.window - 2:
            raise ValueError(f"max_lag ({self.max_lag}) must be at most window - 2 ({self.window - 2}): τc needs "
                             "K < N - 1")
        if (self.activity == "tau_c" or self.tau_c) and (problem := tau_mode_problem(self.mode)):
            raise ValueError(f"{'activity' if self.activity == 'tau_c' else 'tau_c'}: {problem}")
        return self

    @property
    def lags(self) -> int:
        """K, the τc lags in frames (``max_lag`` or its default)."""
        return self.max_lag if self.max_lag is not None else default_max_lag(self.window, self.lag)


class RegionSettings(StrictModel):
    """What a daemon region adds to its shape (``edgedsm.geometry``): a name and drying thresholds.
    Shapes are in camera pixels; a mask's path is relative to the config file."""

    name: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$", description="region name in MQTT")
    wet_above: float | None = Field(None, gt=0, le=1e9, description="activity (estimator.activity's region mean) "
                                                                    "at or above which the surface is wet")
    dry_below: float | None = Field(None, gt=0, le=1e9, description="activity at or below which the surface is dry")
    wet_below_s: float | None = Field(None, gt=0, le=86400,
                                      description="judge on τc instead: the region's correlation time (s) at or "
                                                  "below which the surface is wet (wet decorrelates fast)")
    dry_above_s: float | None = Field(None, gt=0, le=86400,
                                      description="judge on τc: the correlation time (s) at or above which the "
                                                  "surface is dry")
    hysteresis: float = Field(0.05, ge=0, lt=0.5, description="relative margin to leave a state")
    min_dwell_s: float = Field(10.0, ge=0, le=86400, description="a new state must hold this long")
    trend_window_s: float = Field(120.0, gt=0, le=86400, description="time-to-dry trend window")

    @model_validator(mode="after")
    def _thresholds_fit(self) -> RegionSettings:
        on_activity = (self.wet_above, self.dry_below)
        on_tau = (self.wet_below_s, self.dry_above_s)
        if any(v is not None for v in on_activity) and any(v is not None for v in on_tau):
            raise ValueError("give either wet_above/dry_below (activity) or wet_below_s/dry_above_s (τc in "
                             "seconds), not both")
        for pair, names in ((on_activity, "wet_above and dry_below"), (on_tau, "wet_below_s and dry_above_s")):
            if (pair[0] is None) != (pair[1] is None):
                raise ValueError(f"give both {names}")
        if all(v is None for v in (*on_activity, *on_tau)):
            raise ValueError("drying thresholds missing: give wet_above and dry_below (activity), or "
                             "wet_below_s and dry_above_s (τc in seconds)")
        self.thresholds()  # its ValueError names the problem
        return self

    @property
    def on_tau(self) -> bool:
        """Judged on the region's τc in seconds (wet_below_s / dry_above_s)."""
        return self.wet_below_s is not None

    def thresholds(self) -> Thresholds:
        if self.wet_below_s is not None and self.dry_above_s is not None:
            return Thresholds.of_tau(self.wet_below_s, self.dry_above_s, self.hysteresis, self.min_dwell_s,
                                     self.trend_window_s)
        assert self.wet_above is not None and self.dry_below is not None  # the validator checked
        return Thresholds(self.wet_above, self.dry_below, self.hysteresis, self.min_dwell_s, self.trend_window_s)

    def mask(self, shape: tuple[int, int], base_dir: Path) -> np.ndarray:
        """Boolean mask of the region on a frame of ``shape``; an empty region is a ConfigError."""
        mask = self.draw(shape, 1.0, base_dir)  # type: ignore[attr-defined]  # from the shape base
        if not mask.any():
            raise ConfigError(f"regions.{self.name}: the region has no pixel inside the {shape[1]}x{shape[0]} frame")
        return mask


class FullArea(geometry.Full, RegionSettings):
    pass


class RectArea(geometry.Rect, RegionSettings):
    pass


class CircleArea(geometry.Circle, RegionSettings):
    pass


class RingArea(geometry.Ring, RegionSettings):
    pass


class PolygonArea(geometry.Polygon, RegionSettings):
    pass


class TextArea(geometry.Text, RegionSettings):
    pass


class MaskArea(geometry.Mask, RegionSettings):
    pass


def _default_shape(value: object) -> object:
    # `shape` may be left out of a daemon region: the whole frame
    if isinstance(value, dict) and "shape" not in value:
        return {"shape": "full", **value}
    return value


def _shape_of(value: object) -> object:
    if isinstance(value, dict):
        return value.get("shape", "full")
    return getattr(value, "shape", None)


#: A daemon ``[[regions]]`` entry: one of the shapes of ``edgedsm.geometry`` plus RegionSettings.
RegionSection = Annotated[
    Annotated[FullArea, Tag("full")] | Annotated[RectArea, Tag("rect")] | Annotated[CircleArea, Tag("circle")]
    | Annotated[RingArea, Tag("ring")] | Annotated[PolygonArea, Tag("polygon")]
    | Annotated[TextArea, Tag("text")] | Annotated[MaskArea, Tag("mask")],
    Discriminator(_shape_of, custom_error_type="shape", custom_error_message=(
        f"shape must be one of {', '.join(geometry.SHAPE_NAMES)}")),
]


class LoggingSection(StrictModel):
    level: Literal["debug", "info", "warning", "error"] = Field("info", description="log level")
    json_lines: bool = Field(False, description="one JSON object per log line (for log shippers)")


class CadenceSection(StrictModel):
    """``[cadence]``: how often the pipeline evaluates and publishes statistics and maps, for
    every sink (the drying states are judged twice a second whatever these say)."""

    stats_interval_s: float = Field(5.0, ge=0.1, le=3600.0,
                                    description="seconds between statistics messages")
    maps_interval_s: float = Field(60.0, ge=0.1, le=86_400.0,
                                   description="seconds between map messages (cmd/publish_maps asks for one at once)")


class HomeAssistantSection(StrictModel):
    """``[homeassistant]``: MQTT discovery of this device's entities (needs ``[mqtt]``)."""

    discovery_prefix: str = Field("homeassistant", min_length=1, max_length=128, pattern=TOPIC_PREFIX_PATTERN,
                                  description="Home Assistant's discovery prefix (its MQTT integration setting)")
    color_maps: bool = Field(True, description="publish colour-mapped 8-bit PNG maps on <base>/map/<name>/color "
                                               "(with a colour bar) and announce them as image entities")
    colormap: Literal["turbo", "viridis", "inferno", "jet"] = Field("turbo", description="OpenCV colour map")


class HttpSection(StrictModel):
    """``[http]``: Prometheus ``/metrics`` and ``/healthz`` on a small HTTP server."""

    listen: str = Field("127.0.0.1:9108", min_length=3, max_length=64, pattern=r"^[^\s:]+:\d{1,5}$",
                        description="HOST:PORT to listen on (127.0.0.1 keeps it on this machine)")
    stale_after_s: float = Field(10.0, gt=0, le=3600,
                                 description="/healthz says 503 when no frame arrived for this long")

    @field_validator("listen")
    @classmethod
    def _port_in_range(cls, value: str) -> str:
        if not 1 <= int(value.rpartition(":")[2]) <= 65535:
            raise ValueError("the port must be 1..65535")
        return value

    @property
    def address(self) -> tuple[str, int]:
        host, _, port = self.listen.rpartition(":")
        return host, int(port)


def _default_regions() -> list[RegionSection]:
    return [FullArea(name="full", wet_above=0.9, dry_below=0.5)]


class DaemonConfig(StrictModel):
    device: DeviceSection = Field(default_factory=DeviceSection)
    camera: CameraSection = Field(description="the camera; required, never a silent default")
    laser: LaserSection | None = Field(None, description="laser relay; absent = laser not switched by edgedsm")
    acquisition: AcquisitionSection = Field(default_factory=AcquisitionSection)
    estimator: EstimatorSection = Field(default_factory=EstimatorSection)
    regions: Annotated[list[RegionSection], Field(min_length=1, max_length=64)] = Field(
        default_factory=_default_regions, description="regions of interest, each with drying thresholds")
    mqtt: MqttSettings | None = Field(None, description="broker; absent = no publishing")
    sparkplug: SparkplugSettings | None = Field(
        None, description="Sparkplug B edge node on the [mqtt] broker; absent = none (docs/sparkplug.md)")
    cadence: CadenceSection = Field(default_factory=CadenceSection,
                                    description="how often statistics and maps are evaluated and published")
    logging: LoggingSection = Field(default_factory=LoggingSection)
    homeassistant: HomeAssistantSection | None = Field(None, description="Home Assistant discovery; absent = off")
    http: HttpSection | None = Field(None, description="metrics and health over HTTP; absent = off")
    _base_dir: Path = PrivateAttr(default_factory=lambda: Path("."))
    _source: str = PrivateAttr("")
    _notes: list[str] = PrivateAttr(default_factory=list)

    @property
    def notes(self) -> list[str]:
        """Deprecations found while reading the file, one line each (the daemon logs them,
        ``check-config`` prints them)."""
        return list(self._notes)

    @property
    def base_dir(self) -> Path:
        """The directory relative paths (scene, recording, mask) resolve in: the config file's."""
        return self._base_dir

    @property
    def source(self) -> str:
        """The config file's path as given ("" when built in code)."""
        return self._source

    @field_validator("sparkplug")
    @classmethod
    def _sparkplug_needs_mqtt(cls, value: SparkplugSettings | None, info: ValidationInfo) -> SparkplugSettings | None:
        # "mqtt" missing from info.data: its table failed validation and has its own error
        if value is not None and "mqtt" in info.data and info.data["mqtt"] is None:
            raise ValueError("needs an [mqtt] table: the Sparkplug node uses its broker, TLS and credentials")
        return value

    @model_validator(mode="after")
    def _unique_regions(self) -> DaemonConfig:
        names = [r.name for r in self.regions]
        duplicates = sorted({n for n in names if names.count(n) > 1})
        if duplicates:
            raise ValueError(f"region names must be unique: {', '.join(duplicates)}")
        if self.acquisition.mode == "bursts" and self.acquisition.burst_frames < self.estimator.window:
            raise ValueError("bursts mode: burst_frames must be >= estimator.window")
        if self.mqtt is not None and "device" not in self.mqtt.model_fields_set:
            self.mqtt.device = self.device.name  # one name for the instance, its logs and its topics
        if self.homeassistant is not None and self.mqtt is None:
            raise ValueError("[homeassistant] needs [mqtt]: discovery is published on the broker")
        if self.sparkplug is not None and self.sparkplug.edge_node_id is None:
            self.sparkplug.edge_node_id = self.device.name
        self._check_tau_c()
        return self

    @property
    def tau_c_on(self) -> bool:
        """τc is estimated: asked for (estimator.tau_c), judged on (activity = 'tau_c') or needed by a
        region's wet_below_s / dry_above_s."""
        return self.estimator.tau_c or self.estimator.activity == "tau_c" or any(r.on_tau for r in self.regions)

    def _check_tau_c(self) -> None:
        """τc settings that depend on more than one table (messages name the key path)."""
        est = self.estimator
        for index, region in enumerate(self.regions):
            if est.activity == "tau_c" and not region.on_tau:
                raise ValueError(f"regions.{index}.wet_above: estimator.activity = 'tau_c' judges every region on "
                                 "its τc in seconds: give wet_below_s and dry_above_s")
            if region.on_tau and (problem := tau_mode_problem(est.mode)):
                raise ValueError(f"regions.{index}.wet_below_s: τc thresholds in seconds: estimator.mode: {problem}")
        if not self.tau_c_on:
            return
        if est.window < 3:
            raise ValueError("estimator.window: τc needs a window of at least 3 frames (K < N - 1)")
        dt = self.camera.frame_interval_s
        if dt is None:
            return  # known once frames flow: checked then (a warning alert per region, edgedsm.daemon.tau)
        for index, region in enumerate(self.regions):
            if region.wet_below_s is None or region.dry_above_s is None:
                continue
            problem = tau_threshold_problem(region.wet_below_s, region.dry_above_s, region.hysteresis, est.lags, dt)
            if problem:
                raise ValueError(f"regions.{index}: {problem}")


def tau_threshold_problem(wet_below_s: float, dry_above_s: float, hysteresis: float, lags: int,
                          frame_interval_s: float) -> str | None:
    """Why τc thresholds cannot be told apart at this frame interval (None: they can). τc is measured
    from TAU_FLOOR·Δt (Δt/3) up to K·Δt; beyond, only a bound is known (docs/tau_c.md)."""
    top = lags * frame_interval_s
    floor = TAU_FLOOR * frame_interval_s
    # dry is entered at τc >= dry_above_s/(1-h), wet at τc <= wet_below_s/(1+h) (the hysteresis
    # is relative on 1/τc); "above K" reads as τc = K·Δt, "below the floor" as Δt/3
    if dry_above_s / (1 - hysteresis) > top:
        return (f"dry_above_s ({dry_above_s:g} s; {dry_above_s / (1 - hysteresis):.4g} s with the hysteresis) is "
                f"beyond the longest τc measured, estimator.max_lag x Δt = {lags} x {frame_interval_s:g} s = "
                f"{top:g} s: raise max_lag (and window) or lower dry_above_s")
    if wet_below_s / (1 + hysteresis) < floor:
        return (f"wet_below_s ({wet_below_s:g} s; {wet_below_s / (1 + hysteresis):.4g} s with the hysteresis) is "
                f"below the shortest τc measured, Δt/3 = {floor:.4g} s: a faster camera is needed")
    return None


def _cadence_from_mqtt(data: dict, path: Path) -> tuple[dict, list[str]]:
    """``[mqtt]`` stats_interval_s / maps_interval_s, where they once were, moved to ``[cadence]``;
    the keys moved. Both places at once is a ConfigError."""
    mqtt, cadence = data.get("mqtt"), data.get("cadence", {})
    if not isinstance(mqtt, dict) or not isinstance(cadence, dict):
        return data, []
    moved = [key for key in CADENCE_KEYS if key in mqtt]
    if both := [key for key in moved if key in cadence]:
        raise ConfigError(f"{path}: mqtt.{both[0]}: given in both [mqtt] and [cadence]: keep the [cadence] one")
    if not moved:
        return data, []
    return ({**data, "mqtt": {k: v for k, v in mqtt.items() if k not in moved},
             "cadence": {**cadence, **{key: mqtt[key] for key in moved}}}, moved)


def load_config(path: str | Path) -> DaemonConfig:
    """Read and validate a daemon config; ConfigError lists every problem with its key path.

    The camera and relay URIs are parsed here, once, with relative paths resolved against the
    config file's directory; a scene, recording or mask image that cannot be used is refused now.
    """
    path = Path(path)
    data = read_toml(path)
    if isinstance(data.get("regions"), list):  # the default shape as a key, so error paths read as written
        data["regions"] = [_default_shape(region) for region in data["regions"]]
    data, moved = _cadence_from_mqtt(data, path)
    try:
        config = validate(DaemonConfig, data, str(path))
    except ConfigError as exc:  # a moved key's problem is named where the file has it
        message = str(exc)
        for key in moved:
            message = message.replace(f": cadence.{key}:", f": mqtt.{key}:")
        raise ConfigError(message) from None
    config._base_dir, config._source = path.resolve().parent, str(path)
    config._notes = [f"{path}: mqtt.{key} is deprecated: write it as {key} in [cadence] (same meaning)"
                     for key in moved]
    try:
        config.camera.resolve(config.base_dir)
    except ConfigError as exc:
        raise ConfigError(f"{path}: camera.uri: {exc}") from None
    for index, region in enumerate(config.regions):
        # a mask image is read at the first frame: check it now, so that a reload refuses it
        if isinstance(region, geometry.Mask):
            mask_path = region.resolved(config.base_dir)
            if geometry.load_mask_image_or_none(mask_path) is None:
                raise ConfigError(f"{path}: regions.{index}.path: {mask_path} cannot be read as an image")
    return config


class _LaserOnly(StrictModel):
    model_config = ConfigDict(extra="ignore")
    laser: LaserSection | None = None


def load_relay_spec(path: str | Path) -> RelaySpec | None:
    """Only the ``[laser]`` relay of a config file (None when it has none), whatever else in the
    file is wrong: switching the laser off (``edgedsm laser off --config``) must not depend on
    the camera's scene still being there."""
    path = Path(path)
    laser = validate(_LaserOnly, read_toml(path), str(path)).laser
    return laser.spec if laser is not None else None


def check_regions(config: DaemonConfig, frame_shape: tuple[int, int]) -> None:
    """Refuse regions that do not fit a frame of ``frame_shape`` (rows, columns): one with no pixel
    inside, or one reaching outside (its activity would silently cover less than was drawn).
    Pure apart from reading mask images; call it once the camera's frame size is known and
    before the laser goes on. ConfigError has one line per region, with its key path."""
    rows, cols = frame_shape
    prefix = f"{config.source}: " if config.source else ""
    problems = []
    for index, region in enumerate(config.regions):
        where = f"{prefix}regions.{index}: region {region.name!r}"
        if not region.draw(frame_shape, 1.0, config.base_dir).any():
            problems.append(f"{where} has no pixel inside the {cols}x{rows} frame")
        elif sides := geometry.outside_part(region.bounds(), frame_shape):
            problems.append(f"{where} reaches outside the {cols}x{rows} frame ({sides})")
    if problems:
        raise ConfigError("\n".join(problems))


def config_schema() -> dict:
    """JSON Schema of the daemon config (for editors: taplo, VS Code Even Better TOML)."""
    return DaemonConfig.model_json_schema()
