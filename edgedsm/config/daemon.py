"""The daemon configuration as a whole: :class:`DaemonConfig` (every table), reading a file
(:func:`load_config`), and the rules that need more than one table or the camera's frame
(:func:`check_regions`: the one region rule of check-config, the daemon's start and a reload)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from pydantic import ConfigDict, Field, PrivateAttr, field_validator, model_validator
from pydantic_core.core_schema import ValidationInfo

from edgedsm import geometry
from edgedsm.config.devices import AcquisitionSection, CameraSection, DeviceSection, LaserSection
from edgedsm.config.estimator import EstimatorSection
from edgedsm.config.kinetics import KineticsSection, kinetics_problem
from edgedsm.config.outputs import CadenceSection, HomeAssistantSection, HttpSection, LoggingSection
from edgedsm.config.recording import RecordingSection
from edgedsm.config.regions import RegionSection, _default_regions, _default_shape
from edgedsm.devices.uri import RelaySpec
from edgedsm.errors import ConfigError, EstimatorError
from edgedsm.estimators.correlation_time import tau_mode_problem, tau_threshold_problem
from edgedsm.estimators.dft_bins import BandPlan
from edgedsm.publish.settings import CADENCE_KEYS, MqttSettings
from edgedsm.publish.sparkplug.settings import SparkplugSettings
from edgedsm.validation import StrictModel, read_toml, validate


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
    recording: RecordingSection | None = Field(None, description="frames kept on disk (continuous, alert clips, "
                                                                 "time-lapse); absent = none (docs/recording.md)")
    kinetics: KineticsSection = Field(default_factory=KineticsSection,
                                      description="each region's decorrelation time over decades; off by "
                                                  "default (docs/kinetics.md)")
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
    def recording_dir(self) -> Path | None:
        """Where ``[recording]`` writes (None without one): its ``dir`` resolved against the
        config file's folder, else ``<device.state_dir>/recordings``."""
        if self.recording is None:
            return None
        return self.recording.directory(self.base_dir, self.device.state_dir)

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
        if problem := kinetics_problem(self.kinetics, self.estimator.activity, self.regions):
            raise ValueError(problem)
        self._check_tau_c()
        self._check_bands()
        return self

    @property
    def band_args(self) -> dict[str, float | None]:
        """The engine's ``dt`` and ``band_split`` for the band ratio: the split in Hz of the camera's
        frame interval, or (no split given) the default, half the Nyquist frequency in any unit."""
        split = self.estimator.band_split_hz
        return {"dt": self.camera.frame_interval_s if split is not None else None, "band_split": split}

    def _check_bands(self) -> None:
        """The band ratio's split against the camera's frame interval (messages name the key path)."""
        est = self.estimator
        if est.activity != "band_ratio" or est.band_split_hz is None:
            return
        if self.camera.frame_interval_s is None:
            raise ValueError("estimator.band_split_hz: a split in Hz needs camera.frame_interval_s (the frame "
                             "interval in seconds); without band_split_hz the split is half the Nyquist frequency")
        try:
            BandPlan.of(est.window, self.camera.frame_interval_s, est.band_split_hz)
        except EstimatorError as exc:
            raise ValueError(f"estimator.band_split_hz: {exc} (camera.frame_interval_s = "
                             f"{self.camera.frame_interval_s:g} s, estimator.window = {est.window})") from None

    @property
    def tau_c_on(self) -> bool:
        """τc is estimated: asked for (estimator.tau_c), judged on (activity = 'tau_c') or needed by a
        region's wet_below_s / dry_above_s (unless those judge the kinetics: activity = 'kinetics')."""
        return self.estimator.tau_c or self.estimator.activity == "tau_c" or (
            self.estimator.activity != "kinetics" and any(r.on_tau for r in self.regions))

    def _check_tau_c(self) -> None:
        """τc settings that depend on more than one table (messages name the key path)."""
        est = self.estimator
        for index, region in enumerate(self.regions):
            if est.activity == "tau_c" and not region.on_tau:
                raise ValueError(f"regions.{index}.wet_above: estimator.activity = 'tau_c' judges every region on "
                                 "its τc in seconds: give wet_below_s and dry_above_s")
            if region.on_tau and est.activity != "kinetics" and (problem := tau_mode_problem(est.mode)):
                raise ValueError(f"regions.{index}.wet_below_s: τc thresholds in seconds: estimator.mode: {problem}")
        if not self.tau_c_on:
            return
        if est.window < 3:
            raise ValueError("estimator.window: τc needs a window of at least 3 frames (K < N - 1)")
        dt = self.camera.frame_interval_s
        if dt is None:
            return  # known once frames flow: checked then (a warning alert per region, edgedsm.daemon.tau)
        for index, region in enumerate(self.regions):
            if region.wet_below_s is None or region.dry_above_s is None or est.activity == "kinetics":
                continue
            problem = tau_threshold_problem(region.wet_below_s, region.dry_above_s, region.hysteresis, est.lags, dt)
            if problem:
                raise ValueError(f"regions.{index}: {problem}")


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
