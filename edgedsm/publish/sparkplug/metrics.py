"""Which Sparkplug metrics the daemon's typed messages become (pure; see docs/sparkplug.md).

The set is data-driven: every region and every map that a :class:`~edgedsm.messages.Stats`
carries becomes metrics (``regions/<region>/<map>/mean``), so a new estimator (τc) or a new
cause of dropped frames appears without a code change; the node announces it with a new birth.
Metric names use '/' for folders, as Sparkplug hosts (Ignition) expect.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from edgedsm.messages import DROP_CAUSES, Alert, RegionKinetics, RegionSignal, StateReport, Stats
from edgedsm.publish import units
from edgedsm.publish.sparkplug.payload import DataType, Value


def map_unit(name: str) -> str | None:
    """A map's ``engUnit``: the estimators' registry's (``edgedsm.publish.units``); none for a
    dimensionless map or one the registry does not know."""
    unit = units.unit_of(name)
    return None if unit == units.UNKNOWN else units.display_unit(unit)


@dataclass(frozen=True)
class Reading:
    """A metric's current value with its datatype and engineering unit."""

    datatype: DataType
    value: Value
    unit: str | None = None


def _double(value: float | None, unit: str | None = None) -> Reading:
    return Reading(DataType.DOUBLE, value, unit)


def _count(value: int | None, unit: str | None = "frames") -> Reading:
    return Reading(DataType.UINT64, value, unit)


def _text(value: str | None) -> Reading:
    return Reading(DataType.STRING, value)


def _datetime_ms(wall_s: float | None) -> Reading:
    return Reading(DataType.DATETIME, None if wall_s is None else round(wall_s * 1000.0))


def region_readings(region: str, *, state: str | None = None, since: float | None = None,
                    activity: float | None = None, time_to_dry_s: float | None = None,
                    judged: str | None = None) -> dict[str, Reading]:
    """A region's drying metrics (all of them, null where unknown); ``activity`` is of the
    estimator ``judged`` (its unit: :func:`map_unit`; τc: s), none when not known."""
    base = f"regions/{region}"
    return {f"{base}/state": _text(state), f"{base}/since": _datetime_ms(since),
            f"{base}/activity": _double(activity, None if judged is None else map_unit(judged)),
            f"{base}/time_to_dry_s": _double(time_to_dry_s, "s")}


def map_reading(region: str, map_name: str, mean: float | None) -> tuple[str, Reading]:
    """The region mean of one map (one estimator: s1, s2, s3, tau_c ...)."""
    return f"regions/{region}/{map_name}/mean", _double(mean, map_unit(map_name))


def declared_readings(regions: Iterable[str], maps: Iterable[str], *, signal: bool = True,
                      judged: Mapping[str, str] | None = None) -> dict[str, Reading]:
    """Every device metric known before the first message, null-valued, so that the first birth
    already carries the whole set (a later birth adds what appears after). ``signal``: each
    region's signal quality is published (``estimator.noise_floor``, on by default); ``judged``:
    the estimator each region's activity is of (its unit in the birth; a region missing from it
    gets its unit, and a new birth, with its first state report)."""
    readings: dict[str, Reading] = {
        "frames": _count(None), "frames_dropped": _count(None), "fps": _double(None, "frames/s"),
        "ready": Reading(DataType.BOOLEAN, None), "laser": _text(None), "estimator": _text(None),
        "ambient_level": _double(None, "grey levels"), "warning": _text(None),
        "alerts/count": _count(0, None), "alerts/last": _text(None), "alerts/last_type": _text(None),
        "alerts/last_t": _datetime_ms(None),
        **{f"drops/{cause}": _count(None) for cause in DROP_CAUSES},  # every cause from the first birth
    }
    map_names = [name for name in maps if name != "tau_c"]  # τc: one pooled value per region, not a map mean
    for region in regions:
        readings.update(region_readings(region, judged=(judged or {}).get(region)))
        readings.update(map_reading(region, name, None) for name in map_names)
        if "tau_c" in maps:
            readings.update(tau_readings(region))
        if signal:
            readings.update(signal_readings(region))
    if "tau_c" in maps:
        readings["frame_interval_s"] = _double(None, "s")
    return readings


def tau_readings(region: str, tau_c_s: float | None = None, status: str | None = None) -> dict[str, Reading]:
    """A region's τc in seconds (its pooled fit) and its status (measured, above, below, no_signal)."""
    return {f"regions/{region}/tau_c_s": _double(tau_c_s, "s"), f"regions/{region}/tau_c_status": _text(status)}


def kinetics_readings(region: str, reading: RegionKinetics) -> dict[str, Reading]:
    """A region's decorrelation time over decades (``[kinetics]``) in the registry's unit (τ, or
    its bound when above / below; null where there is none) and its status."""
    value = reading.tau_s if reading.tau_s is not None else reading.bound_s
    return {f"regions/{region}/kinetics": _double(value, map_unit("kinetics")),
            f"regions/{region}/kinetics_status": _text(reading.status)}


#: A region's signal metrics: name under ``regions/<region>/``, the ``RegionSignal`` field, its
#: datatype and unit. The floor and the activity above it are in the judged estimator's units (a
#: region judged on τc: the signal's share of the variance), so they carry none.
SIGNAL_METRICS = (
    ("signal", "signal", DataType.STRING, None), ("signal_reason", "reason", DataType.STRING, None),
    ("above_noise", "above_noise", DataType.DOUBLE, None),
    ("above_noise_spread", "above_noise_spread", DataType.DOUBLE, None),
    ("noise_floor", "noise_floor", DataType.DOUBLE, None), ("mean_intensity", "mean", DataType.DOUBLE, "grey levels"),
    ("dark_fraction", "dark_fraction", DataType.DOUBLE, None),
    ("saturated_fraction", "saturated_fraction", DataType.DOUBLE, None),
    ("speckle_contrast", "speckle_contrast", DataType.DOUBLE, None),
    ("intensity_change", "intensity_change", DataType.DOUBLE, None),
)


def signal_readings(region: str, signal: RegionSignal | None = None) -> dict[str, Reading]:
    """A region's signal quality (ok, low, dark, saturated, not_speckle), why it is not ok, and its
    light and activity against the camera's noise (docs/noise.md); all null without ``signal``."""
    return {f"regions/{region}/{name}": Reading(datatype, None if signal is None else getattr(signal, field), unit)
            for name, field, datatype, unit in SIGNAL_METRICS}


def stats_readings(stats: Stats) -> dict[str, Reading]:
    """The metrics of one statistics message."""
    readings: dict[str, Reading] = {
        "frames": _count(stats.frames), "frames_dropped": _count(sum(stats.drops.values())),
        "fps": _double(stats.fps, "frames/s"), "ready": Reading(DataType.BOOLEAN, stats.ready),
        "laser": _text(stats.laser), "estimator": _text(stats.estimator),
        "ambient_level": _double(stats.ambient_level, "grey levels"), "warning": _text(stats.warning),
    }
    readings.update((f"drops/{cause}", _count(count)) for cause, count in stats.drops.items())
    for region, per_map in stats.regions.items():
        readings.update(map_reading(region, name, map_stats.mean) for name, map_stats in per_map.items())
    readings.update((f"regions/{region}/state", _text(state)) for region, state in stats.states.items())
    for region, tau in stats.tau_c.items():
        readings.update(tau_readings(region, tau.tau_c_s, tau.status))
    for region, signal in stats.signal.items():
        readings.update(signal_readings(region, signal))
    for region, kinetics in stats.kinetics.items():
        readings.update(kinetics_readings(region, kinetics))
    if stats.frame_interval_s is not None:
        readings["frame_interval_s"] = _double(stats.frame_interval_s, "s")
    return readings


def state_readings(report: StateReport) -> dict[str, Reading]:
    """The metrics of one state report: each region's state, since, activity (in its estimator's
    unit) and time to dry."""
    readings: dict[str, Reading] = {"laser": _text(report.laser), "estimator": _text(report.estimator)}
    for name, region in report.regions.items():
        readings.update(region_readings(name, state=region.state, since=region.since, activity=region.activity,
                                        time_to_dry_s=region.time_to_dry_s,
                                        judged=region.estimator or report.estimator))
    return readings


def alert_readings(alert: Alert, count: int) -> dict[str, Reading]:
    """The latest alert as metrics (Sparkplug has no events; the JSON sink delivers every alert)."""
    return {"alerts/count": _count(count, None), "alerts/last": _text(alert.describe()),
            "alerts/last_type": _text(str(alert.kind)), "alerts/last_t": _datetime_ms(alert.t)}
