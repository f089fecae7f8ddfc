"""The ``[sparkplug]`` table of the daemon config: the Sparkplug B 3.0 edge node's identity, the
primary host it waits for, and report-by-exception. The broker, TLS and credentials are those of
``[mqtt]`` (a Sparkplug node needs it). See docs/sparkplug.md."""

from __future__ import annotations

from pydantic import Field

from edgedsm.validation import StrictModel

#: A Sparkplug ID (group, edge node, device, host): UTF-8 without '+', '/', '#' (spec, topic
#: namespace: tck-id-topic-structure-namespace-valid-group-id and its siblings),
#: and without control characters (they break topic filters and logs).
SPARKPLUG_ID = r"^[^+/#\x00-\x1f\x7f]+$"


class SparkplugSettings(StrictModel):
    """A Sparkplug B 3.0 edge node on the ``[mqtt]`` broker, with its own MQTT session."""

    group_id: str = Field(
        min_length=1, max_length=64, pattern=SPARKPLUG_ID,
        description="Sparkplug group ID (topic spBv1.0/<group_id>/...), e.g. the line or cell; "
                    "no '+', '/' or '#'")
    edge_node_id: str | None = Field(
        None, min_length=1, max_length=64, pattern=SPARKPLUG_ID,
        description="Sparkplug edge node ID; default: the device name ([device] name). "
                    "Group and edge node ID together must be unique on the broker")
    device_id: str = Field(
        "camera", min_length=1, max_length=64, pattern=SPARKPLUG_ID,
        description="Sparkplug device ID of the camera and its regions (DBIRTH/DDATA)")
    primary_host_id: str | None = Field(
        None, min_length=1, max_length=64, pattern=SPARKPLUG_ID,
        description="host ID of the primary host application (e.g. Ignition's); when set, births wait "
                    "until spBv1.0/STATE/<primary_host_id> says online, and the session restarts when "
                    "it says offline. Absent: publish as soon as connected")
    client_id: str | None = Field(
        None, min_length=1, max_length=128, pattern=r"^[\x21-\x7e]+$",
        description="MQTT client id of the Sparkplug session; default: the [mqtt] client id + '-sparkplug'")
    deadband_rel: float = Field(
        0.01, ge=0.0, le=1.0,
        description="report-by-exception: a float metric is sent again when it moved by more than this "
                    "fraction of its last sent value (0 = every change)")
    deadband_abs: float = Field(
        0.0, ge=0.0, le=1e9,
        description="report-by-exception: ... or by more than this absolute amount, whichever is larger")
    rebirth_min_interval_s: float = Field(
        2.0, ge=0.0, le=3600.0,
        description="births at most this often: rebirth requests (NCMD) arriving sooner are answered by "
                    "one birth when the interval is over (a rebirth flood cannot saturate the link)")
