"""Typed messages the daemon emits: region states, alerts, statistics and maps.

Every sink (MQTT JSON, and the Sparkplug B / Home Assistant / Prometheus sinks to come) receives
these, and every consumer (``edgedsm watch``, the tests, the dashboard) parses the same types,
so the wire format is defined once, here. ``docs/mqtt.md`` documents each field with an example.

Clock convention: every time in a message (``t``, ``since``) is wall-clock UTC in seconds since
the Unix epoch. Inside the daemon, time is monotonic (immune to clock steps); it is converted
once, at the boundary, with :meth:`Clock.to_wall`.

Parsing is tolerant of keys it does not know (a newer daemon may add fields), strict about the
ones it does (types and bounds are checked, a bad payload raises ``pydantic.ValidationError``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any, ClassVar, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, SerializerFunctionWrapHandler, field_validator, model_serializer

from edgedsm import _json

#: States a region can be in (``edgedsm.drying.DryingState`` values).
RegionStateName = Literal["warming_up", "wet", "drying", "dry", "fault"]
#: The laser as the daemon knows it: ``unknown`` after any relay error (never guessed).
LaserState = Literal["on", "off", "unknown"]
#: Whether the daemon that published a state is running (the ``<base>/availability`` words).
Availability = Literal["online", "offline"]
#: What a published τc is (``edgedsm.estimators.correlation_time`` statuses): ``measured``; ``above``:
#: no decorrelation within K lags, τc is at least the value (K·Δt); ``below``: decorrelated within one
#: frame, τc is at most the value (Δt/3); ``no_signal``: σ = 0 (laser off, saturated), value 0.
TauStatus = Literal["measured", "above", "below", "no_signal"]
#: A region's signal quality (``edgedsm.estimators.signal_quality``; docs/noise.md): ``ok``; ``low``:
#: the activity is within the camera's noise; ``dark``, ``saturated``, ``not_speckle``: the light
#: cannot be judged (the region keeps its state).
SignalName = Literal["ok", "low", "dark", "saturated", "not_speckle"]
#: What a region's kinetics reading is (``edgedsm.estimators.kinetics`` statuses; docs/kinetics.md):
#: ``ok``; ``above``: τ is longer than the oldest reference (``bound_s``); ``below``: shorter than one
#: frame interval (``bound_s``); ``dark``, ``saturated``, ``not_speckle``: no light to time, never a
#: number; ``warming_up``: no reference frame yet.
KineticsStatus = Literal["ok", "above", "below", "dark", "saturated", "not_speckle", "warming_up"]


@dataclass(frozen=True)
class Clock:
    """The daemon's two clocks: ``monotonic`` for intervals, ``wall`` (UTC epoch s) for messages."""

    monotonic: Callable[[], float] = time.monotonic
    wall: Callable[[], float] = time.time

    def to_wall(self, monotonic_t: float) -> float:
        """Wall-clock time (UTC epoch s) of an instant given on the monotonic clock."""
        return self.wall() - (self.monotonic() - monotonic_t)


class Message(BaseModel):
    """Base of the JSON messages: immutable, unknown keys ignored when parsing."""

    model_config = ConfigDict(frozen=True, extra="ignore", populate_by_name=True)
    #: Fields left out of the payload while None: docs/mqtt.md says when they are present.
    omitted_when_none: ClassVar[frozenset[str]] = frozenset()

    @model_serializer(mode="wrap")
    def _leave_out_absent(self, handler: SerializerFunctionWrapHandler) -> Any:
        data = handler(self)
        if isinstance(data, dict):
            fields = type(self).model_fields
            for name in self.omitted_when_none:
                for key in (name, fields[name].alias):
                    if key is not None and key in data and data[key] is None:
                        del data[key]
        return data

    def to_json(self) -> dict[str, Any]:
        """The payload as published: field aliases, enums as strings, non-finite floats as null."""
        return _json.jsonable(self.model_dump(mode="python", by_alias=True))

    def to_bytes(self) -> bytes:
        """Compact UTF-8 JSON of :meth:`to_json`."""
        return _json.dumps(self.to_json())


class RegionState(Message):
    """The drying state of one region (``<base>/state`` and ``<base>/state/<region>``)."""

    omitted_when_none: ClassVar[frozenset[str]] = frozenset({"estimator", "tau_c_status", "signal", "kinetics"})

    region: str = Field(description="region name from the config")
    state: RegionStateName = Field(description="drying state")
    since: float = Field(description="when the region entered this state, UTC epoch s")
    activity: float | None = Field(None, description="latest region mean of the judged estimator, above the "
                                                     "camera's noise floor with estimator.noise_floor (docs/noise.md); "
                                                     "a region judged on τc: its τc in seconds (see ``estimator``)")
    plain: float | None = Field(None, description="the plain statistic ``activity`` is judged from: the region "
                                                  "mean of the judged estimator's map with no noise floor taken off "
                                                  "(a region judged on τc: its τc in s, as ``activity``); None "
                                                  "before the first")
    time_to_dry_s: float | None = Field(None, ge=0, description="extrapolated seconds until dry; 0 when dry")
    estimator: str | None = Field(None, description="what ``activity`` is when not the report's estimator: "
                                                    "'tau_c' (τc in s: small = wet, large = dry)")
    tau_c_status: TauStatus | None = Field(None, description="judged on τc: measured, or what the bound means "
                                                             "(above: τc >= activity; below: τc <= activity)")
    signal: SignalName | None = Field(None, description="the region's signal quality (with estimator.noise_floor); "
                                                        "dark, saturated or not_speckle: the state is held")
    kinetics: RegionKinetics | None = Field(None, description="its decorrelation time and rate ([kinetics] on)")


class RegionSignal(Message):
    """A region's light and its activity against the camera's noise (docs/noise.md), from the last
    N frames of the pixels ``view`` names (the daemon: a patch at its centre, ``estimator.noise_patch``)."""

    omitted_when_none: ClassVar[frozenset[str]] = frozenset({"view"})

    signal: SignalName = Field(description="ok, low (activity within the noise), dark, saturated, not_speckle")
    mean: float = Field(ge=0, description="mean intensity over the window, grey levels")
    dark_fraction: float = Field(ge=0, le=1, description="share of pixels within 3 noise σ of the dark level")
    saturated_fraction: float = Field(ge=0, le=1, description="share of the window's samples (pixels × frames) "
                                                                        "at full scale")
    speckle_contrast: float = Field(ge=0, description="spatial speckle contrast of the last frame, noise removed")
    noise_floor: float | None = Field(None, description="the judged estimator's value for a static surface with "
                                                        "this light (its units; S3: 2/√π); None: no noise model yet")
    above_noise: float | None = Field(None, description="the region's activity above the floor (S3: S3 of the "
                                                        "signal alone)")
    above_noise_spread: float | None = Field(None, ge=0, description="1-σ spread of above_noise around 0 for "
                                                                     "noise alone")
    noise_model: str | None = Field(None, description="where the noise model comes from: datasheet or frames")
    intensity_change: float | None = Field(None, gt=0, description="mean intensity now / when the window first "
                                                                   "filled")
    reason: str | None = Field(None, description="why the signal is not ok, or why there is no floor yet")
    view: str | None = Field(None, max_length=80, description="the pixels the light and the noise were judged on: "
                                                              "'region' (every pixel of it) or 'patch SxS px at "
                                                              "the region's centre' (estimator.noise_patch = S)")


class RegionActivity(Message):
    """What a region's drying thresholds judge, with what it is of and its unit (``activity`` in
    the stats: the same number as the state report's ``activity``)."""

    value: float | None = Field(description="the judged value; None: held (the light cannot be judged) or none yet")
    estimator: str = Field(description="what it is of: the report's estimator, or 'tau_c' for a region judged on τc")
    unit: str = Field(description="its unit ('1': dimensionless; τc: 's'), from the estimators' registry")
    basis: Literal["above_noise", "plain"] = Field(description="above_noise: above the camera's noise floor "
                                                               "(estimator.noise_floor); plain: the region mean "
                                                               "(or τc) itself: no noise model yet, floor off, τc")


def judged_activity(report: StateReport, signal: Mapping[str, RegionSignal]) -> dict[str, RegionActivity]:
    """Each region's judged activity of ``report`` (its ``activity``), for the stats: its
    estimator, unit (``edgedsm.estimators.registry``) and whether it is above the noise floor
    (the region's ``signal`` has a floor and it is not judged on τc)."""
    from edgedsm.estimators import registry  # imported when used: `edgedsm cmd` starts without it

    def unit(name: str) -> str:
        try:
            return registry.get(name).unit
        except KeyError:
            return "?"

    activity = {}
    for name, region in report.regions.items():
        estimator = region.estimator or report.estimator
        floored = estimator not in ("tau_c", "kinetics") and name in signal and signal[name].noise_floor is not None
        activity[name] = RegionActivity(value=region.activity, estimator=estimator, unit=unit(estimator),
                                        basis="above_noise" if floored else "plain")
    return activity


class RegionKinetics(Message):
    """A region's drying kinetics (docs/kinetics.md): the age at which its two-time correlation
    falls to 1/e, in seconds, and its rate; a status, never a number, where there is none."""

    status: KineticsStatus = Field(description="ok; above / below (bound_s); dark, saturated, not_speckle; "
                                               "warming_up")
    tau_s: float | None = Field(None, gt=0, description="decorrelation time τ in s (status ok)")
    rate_hz: float | None = Field(None, gt=0, description="its rate 1/τ in Hz (status ok)")
    bound_s: float | None = Field(None, gt=0, description="above: τ is longer than this (the oldest reference); "
                                                          "below: shorter (one frame interval)")
    frame: int | None = Field(None, ge=0, description="the frame it was read at, counted from the first kept")
    stages: dict[str, float] = Field(default_factory=dict, description="[kinetics] stages reached -> when, UTC "
                                                                       "epoch s (the rate's first reading at or "
                                                                       "below the stage's, held stage_dwell_s)")
    next_stage: str | None = Field(None, description="the next stage not yet reached (None: all, or none set)")
    time_to_next_stage_s: float | None = Field(None, ge=0, description="time to it from the rate's trend, s "
                                                                       "(None: no trend toward it yet)")


class RegionTau(Message):
    """A region's correlation time from its pooled correlations (docs/tau_c.md), in seconds."""

    tau_c_s: float = Field(ge=0, description="τc in seconds (a bound when status is above or below; 0: no signal)")
    status: TauStatus = Field(description="measured, above (τc >= tau_c_s), below (τc <= tau_c_s) or no_signal")


#: Relative change of a region's activity worth republishing the state report for.
ACTIVITY_MOVE = 0.05
#: Relative and absolute (s) change of a time to dry worth republishing the state report for.
TIME_TO_DRY_MOVE = 0.1
TIME_TO_DRY_MOVE_S = 30.0


def _moved(new: float | None, old: float | None, relative: float, absolute: float = 0.0) -> bool:
    if new is None or old is None:
        return (new is None) != (old is None)
    return abs(new - old) > max(relative * abs(old), absolute)


def _region_moved(new: RegionState, old: RegionState) -> bool:
    return (new.state != old.state or new.since != old.since
            or _moved(new.activity, old.activity, ACTIVITY_MOVE) or new.tau_c_status != old.tau_c_status
            or new.signal != old.signal
            or _moved(new.time_to_dry_s, old.time_to_dry_s, TIME_TO_DRY_MOVE, TIME_TO_DRY_MOVE_S))


class StateReport(Message):
    """Every region's state at once (retained on ``<base>/state``)."""

    t: float = Field(description="UTC epoch s")
    estimator: str = Field(description="estimator the states are judged on (s1, s2, s3, tau_c, contrast, fujii, im, "
                                       "gd, band_ratio)")
    laser: LaserState = Field("off", description="the laser relay as last confirmed")
    availability: Availability = Field("online", description="offline: the daemon stopped and this is its last "
                                                             "word (laser as confirmed at stop, no time to dry)")
    regions: dict[str, RegionState] = Field(default_factory=dict, description="by region name")

    def stopped(self, t: float, laser: LaserState) -> StateReport:
        """The report a stopping daemon leaves retained: ``offline``, the laser as confirmed at
        stop, each region's last state kept but no time to dry (nothing extrapolates any more)."""
        regions = {name: region.model_copy(update={"time_to_dry_s": None}) for name, region in self.regions.items()}
        return self.model_copy(update={"t": t, "laser": laser, "availability": "offline", "regions": regions})

    def moved_from(self, previous: StateReport) -> bool:
        """Whether this report says something ``previous`` did not: a state, the laser, a region,
        an activity (by more than ``ACTIVITY_MOVE``) or a time to dry (by more than
        ``TIME_TO_DRY_MOVE`` of itself, or ``TIME_TO_DRY_MOVE_S``) changed — worth republishing."""
        if (self.laser != previous.laser or self.availability != previous.availability
                or self.regions.keys() != previous.regions.keys()):
            return True
        return any(_region_moved(region, previous.regions[name]) for name, region in self.regions.items())


class AlertKind(StrEnum):
    """What an alert reports."""

    TRANSITION = "transition"  # a region changed drying state
    RESET = "reset"            # measurement restarted (reload, rebaseline): states start again
    FAULT = "fault"            # no trustworthy data (camera lost, laser unknown, storage)
    WARNING = "warning"        # measuring goes on, but something needs attention
    STAGE = "stage"            # a region reached a drying stage of [kinetics] (its rate fell to the stage's)


class Alert(Message):
    """One event on ``<base>/alerts`` (QoS 1, durable; ``stream`` + ``seq`` identify it)."""

    omitted_when_none: ClassVar[frozenset[str]] = frozenset({"from_state", "to_state", "activity"})

    kind: AlertKind = Field(alias="type", description="transition, reset, fault, warning or stage")
    t: float = Field(description="UTC epoch s")
    reason: str = Field("", description="why, in words")
    region: str | None = Field(None, description="region concerned (None: the whole device)")
    from_state: RegionStateName | None = Field(None, alias="from", description="transition: state left")
    to_state: RegionStateName | None = Field(None, alias="to", description="transition: state entered")
    activity: float | None = Field(None, description="activity that caused it, if any")
    seq: int | None = Field(None, ge=1, description="set by the alert queue: 1, 2, 3... per stream")
    stream: str | None = Field(None, description="set by the alert queue: id of the durable queue")

    def describe(self) -> str:
        """One line for logs and ``edgedsm watch``."""
        where = f"{self.region}: " if self.region else ""
        change = f"{self.from_state} -> {self.to_state}" if self.kind == AlertKind.TRANSITION else str(self.kind)
        return f"{where}{change}" + (f" - {self.reason}" if self.reason else "")


class MapStats(Message):
    """Statistics of one map over one region (units of the map)."""

    pixels: int = Field(ge=0)
    mean: float | None
    std: float | None
    p05: float | None
    median: float | None
    p95: float | None


class RecordingStats(Message):
    """What ``[recording]`` kept and lost so far (``recording`` in the stats)."""

    mode: str = Field(description="continuous, alerts or timelapse")
    dir: str = Field(description="the recordings' folder")
    files: int = Field(ge=0, description="recordings in the folder (written by this device, kept by retention)")
    bytes: int = Field(ge=0, description="their total size")
    frames_written: int = Field(ge=0, description="frames written since start")
    frames_dropped: int = Field(ge=0, description="frames meant for the disk but dropped (queue full, disk error)")
    queued: int = Field(0, ge=0, description="frames waiting for the disk")
    clip_active: bool = Field(False, description="an alert or cmd/record clip is being recorded")
    files_deleted: int = Field(0, ge=0, description="files deleted by retention since start")
    error: str | None = Field(None, description="the disk's refusal while recording fails (None: writing)")


#: The causes of dropped frames, each counted in the stats' ``drops`` from start (at 0), so a
#: rate over them (Prometheus ``increase()``) has a series before the first drop.
DROP_CAUSES = ("dropped_queue", "dropped_invalid")


class Stats(Message):
    """Periodic statistics (``<base>/stats``, every ``stats_interval_s``)."""

    omitted_when_none: ClassVar[frozenset[str]] = frozenset({"frame_interval_s", "mqtt", "recording"})

    t: float = Field(description="UTC epoch s")
    frames: int = Field(ge=0, description="frames taken off the queue since start")
    ready: bool = Field(description="the estimator window is full")
    fps: float = Field(ge=0, description="frames per second over the last 64 frames")
    laser: LaserState = Field(description="the laser relay as last confirmed")
    estimator: str = Field(description="estimator the states are judged on")
    drops: dict[str, int] = Field(default_factory=dict, validate_default=True,
                                  description="frames dropped, by cause (every cause of "
                                                                   "DROP_CAUSES from start, at 0)")
    camera: dict[str, float | int | str | None] = Field(default_factory=dict, description="camera driver counters")
    ambient_level: float | None = Field(None, description="mean of the latest dark frames, grey levels")
    activity: dict[str, RegionActivity] = Field(default_factory=dict,
                                                description="region -> the value its thresholds judge (the state "
                                                            "report's activity), its estimator and unit")
    regions: dict[str, dict[str, MapStats]] = Field(default_factory=dict,
                                                    description="region -> map -> statistics of the plain map")
    states: dict[str, RegionStateName] = Field(default_factory=dict, alias="state",
                                               description="region -> drying state")
    warning: str | None = Field(None, description="a condition that makes a map unreliable")
    tau_c: dict[str, RegionTau] = Field(default_factory=dict, description="region -> τc in seconds and its status "
                                                                          "(when τc is estimated)")
    frame_interval_s: float | None = Field(None, gt=0, description="Δt that puts τc in seconds (when τc is estimated)")
    kinetics: dict[str, RegionKinetics] = Field(default_factory=dict,
                                                description="region -> its decorrelation time (s), rate (Hz) and "
                                                            "status ([kinetics] on)")
    signal: dict[str, RegionSignal] = Field(default_factory=dict,
                                            description="region -> its light and its activity against the noise "
                                                        "(estimator.noise_floor)")
    mqtt: dict[str, Any] | None = Field(None, description="the MQTT sink's own counters (added on the wire)")
    recording: RecordingStats | None = Field(None, description="the recorder's counters (with [recording])")

    @field_validator("drops")
    @classmethod
    def _every_cause(cls, drops: dict[str, int]) -> dict[str, int]:
        return {**dict.fromkeys(DROP_CAUSES, 0), **drops}


@dataclass(frozen=True)
class MapFrame:
    """One activity map as computed (float64, units of the estimator), with where it came from.

    ``values`` must not be modified after it is handed over (``SlidingWindow.maps()`` makes new
    arrays); sinks read it on their own threads.
    """

    name: str
    values: np.ndarray
    seq: int
    t: float
    window: int
    lag: int
    extra: Mapping[str, Any] = field(default_factory=dict)

    def meta(self) -> dict[str, Any]:
        """What goes beside the picture (the codec adds scale, offset, shape, checksum)."""
        return {**self.extra, "seq": self.seq, "t": self.t, "window": self.window, "lag": self.lag}
