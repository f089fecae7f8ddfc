"""A transactional reload: the new configuration is built and checked completely before the
running pipeline is touched.

Checked, in order: the file (read, parsed, validated; any error — not UTF-8, too deep, a bad
key — is a refusal, never a traceback), the camera (its URI and scene; a camera other than the
running one is opened and must deliver a frame), the regions (each must have pixels inside that
frame), the laser relay (one other than the running one must answer a switch-off). Anything
wrong raises :class:`ReloadRefused` with the reason, and the daemon keeps its running
configuration.
"""

from __future__ import annotations

import logging
from pathlib import Path

from edgedsm.config import DaemonConfig, load_config
from edgedsm.daemon.devices import open_camera_for
from edgedsm.daemon.preflight import preflight
from edgedsm.devices.laser import open_relay
from edgedsm.errors import ConfigError, DeviceError, EdgedsmError
from edgedsm.validation import same_settings

log = logging.getLogger(__name__)


class ReloadRefused(EdgedsmError):
    """The new configuration cannot run; the message says why (first line: a summary)."""


def _same_camera(new: DaemonConfig, running: DaemonConfig) -> bool:
    return new.camera.uri == running.camera.uri and new.base_dir == running.base_dir


def _probe_frame_shape(config: DaemonConfig) -> tuple[int, int]:
    """Open the configured camera, take one frame, close it: the frame's (rows, columns)."""
    camera = open_camera_for(config)
    try:
        camera.open()
        if config.camera.pixel_format:
            camera.set_pixel_format(config.camera.pixel_format)
        for frame in camera.frames(1, timeout_s=config.camera.grab_timeout_s):
            return frame.shape
        raise DeviceError(f"{config.camera.uri}: the camera delivered no frame")
    finally:
        camera.close()


def check_reload(path: Path, running: DaemonConfig, running_shape: tuple[int, int] | None) -> DaemonConfig:
    """The configuration in ``path``, checked as the module docstring says; raises ``ReloadRefused``.

    ``running_shape``: the running camera's frame shape (None before its first frame).
    """
    try:
        new = load_config(path)
    except ConfigError as exc:
        raise ReloadRefused(f"bad configuration:\n{exc}") from exc
    except Exception as exc:  # not UTF-8, nested too deep, unreadable: a refusal, not a crash
        raise ReloadRefused(f"{path}: cannot be read as a configuration: {type(exc).__name__}: {exc}") from exc
    try:
        open_camera_for(new)  # the URI and scene file; opens nothing
        # the running camera cannot be opened twice: its frame is known
        shape = running_shape if _same_camera(new, running) else _probe_frame_shape(new)
        # the rules check-config and the daemon's start apply; memory: checked when the new engine
        # is built, once the running one is freed
        preflight(new, shape, memory=False)
        if new.laser is not None and (running.laser is None or new.laser.uri != running.laser.uri):
            relay = open_relay(new.laser.uri)
            try:
                relay.off()  # the new laser must answer; off is where it must be anyway
            finally:
                relay.detach()
    except EdgedsmError as exc:
        raise ReloadRefused(f"the new configuration cannot run: {exc}") from exc
    return new


# -- what a reload changes ----------------------------------------------------------------------

#: A change applied to the running measurement: the MQTT session(s), the estimator window and
#: the drying states are kept.
KEEP = "keep"
#: A change that needs new measurement: the pipeline restarts after a ``reset`` alert.
RESTART = "restart"

#: Each config section, what a change of it needs (``docs/architecture.md``, "Reload"). A region
#: is split further: its drying thresholds are applied to the running state machine (KEEP), its
#: name and geometry need new masks (RESTART). Sinks whose settings changed are rebuilt either way.
SECTION_CHANGE: dict[str, str] = {
    "device": KEEP,         # topics and alert queue: the publishing sinks are rebuilt
    "camera": RESTART,
    "laser": RESTART,
    "acquisition": RESTART,
    "estimator": RESTART,
    "regions": RESTART,     # names and geometry; thresholds only: KEEP (see region_change)
    "mqtt": KEEP,
    "sparkplug": KEEP,
    "cadence": KEEP,        # applied to the running loop
    "logging": KEEP,
    "homeassistant": KEEP,
    "http": KEEP,
    "recording": KEEP,      # the recorder is rebuilt beside the running measurement
    "kinetics": RESTART,    # each region's reference frames are built for its settings
}

#: Fields of restarting sections that the evaluator applies in place (the noise model's datasheet,
#: the light-change factor): a change of these alone keeps the measurement.
APPLIED_FIELDS = {"camera": frozenset({"noise"}), "estimator": frozenset({"intensity_change"})}

#: The region fields that are drying thresholds (applied in place); every other one is geometry.
THRESHOLD_FIELDS = frozenset({"wet_above", "dry_below", "wet_below_s", "dry_above_s", "hysteresis", "min_dwell_s",
                              "trend_window_s"})


def changed_sections(new: DaemonConfig, running: DaemonConfig) -> list[str]:
    """The config sections whose settings differ, in the table's order (cached, derived state
    such as a parsed URI does not count: :func:`~edgedsm.validation.same_settings`)."""
    return [name for name in SECTION_CHANGE if not same_settings(getattr(new, name), getattr(running, name))]


def _applied_only(name: str, new: DaemonConfig, running: DaemonConfig) -> bool:
    """Whether section ``name`` differs only in fields the evaluator applies in place."""
    fields = APPLIED_FIELDS.get(name)
    if fields is None:
        return False
    old, fresh = getattr(running, name), getattr(new, name)
    return fresh.model_dump(exclude=set(fields)) == old.model_dump(exclude=set(fields)) and \
        same_settings(fresh.model_copy(update={f: getattr(old, f) for f in fields}), old)


def _geometry(config: DaemonConfig) -> list[tuple[str, dict[str, object]]]:
    return [(type(r).__name__, r.model_dump(exclude=THRESHOLD_FIELDS)) for r in config.regions]


def restart_reasons(new: DaemonConfig, running: DaemonConfig) -> list[str]:
    """Why the measurement must restart (empty: the reload is applied to it while it runs)."""
    reasons = [name for name in changed_sections(new, running) if SECTION_CHANGE[name] == RESTART
               and name != "regions" and not _applied_only(name, new, running)]
    if new.base_dir != running.base_dir:
        reasons.append("configuration directory")
    if _geometry(new) != _geometry(running):
        reasons.append("regions")
    if new.tau_c_on != running.tau_c_on:  # τc thresholds added or removed: the engine keeps other sums
        reasons.append("τc on/off")
    elif any(a.on_tau != b.on_tau for a, b in zip(new.regions, running.regions, strict=False)):
        reasons.append("regions judged on τc")  # what the evaluator reads per region
    return reasons
