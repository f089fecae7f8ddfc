"""Daemon configuration (TOML), validated with pydantic: unknown keys refused, every field
bounded and described, types strict. ``edgedsm check-config FILE`` prints every problem with its
key path and exits 78; ``edgedsm check-config --schema`` prints the JSON Schema for editors.
The camera and relay URIs are parsed here, once (``config.camera.spec``, ``config.laser.spec``).
See docs/configuration.md.

The models hold data and its validation, one module per group of tables (``devices``,
``estimator``, ``regions``, ``outputs``, ``recording``; ``daemon``: the whole file and the rules across tables);
masks come from :mod:`edgedsm.geometry`, τc's limits from :mod:`edgedsm.estimators`.

Secrets never live in this file: the MQTT password comes from the environment or from
``$CREDENTIALS_DIRECTORY`` (see ``[mqtt]``).
"""

from __future__ import annotations

from edgedsm.config.daemon import DaemonConfig, check_regions, config_schema, load_config, load_relay_spec
from edgedsm.config.devices import AcquisitionSection, CameraSection, DeviceSection, LaserSection
from edgedsm.config.estimator import EstimatorSection
from edgedsm.config.outputs import CadenceSection, HomeAssistantSection, HttpSection, LoggingSection
from edgedsm.config.recording import RecordingSection
from edgedsm.config.regions import (
    CircleArea,
    FullArea,
    MaskArea,
    PolygonArea,
    RectArea,
    RegionSection,
    RegionSettings,
    RingArea,
    TextArea,
)

__all__ = [
    "AcquisitionSection",
    "CadenceSection",
    "CameraSection",
    "CircleArea",
    "DaemonConfig",
    "DeviceSection",
    "EstimatorSection",
    "FullArea",
    "HomeAssistantSection",
    "HttpSection",
    "LaserSection",
    "LoggingSection",
    "MaskArea",
    "PolygonArea",
    "RecordingSection",
    "RectArea",
    "RegionSection",
    "RegionSettings",
    "RingArea",
    "TextArea",
    "check_regions",
    "config_schema",
    "load_config",
    "load_relay_spec",
]
