"""Sparkplug B payloads through the official protobuf schema (``proto/sparkplug_b.proto``).

Only the parts edgedsm uses: scalar metrics (with ``is_null``), a unit property on births, and
the decoding of commands. Times are UTC milliseconds since the epoch, as the spec requires.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

from google.protobuf.message import DecodeError

from edgedsm.publish.sparkplug.proto import sparkplug_b_pb2 as pb

#: A metric's value as edgedsm holds it (None: null).
Value = bool | int | float | str | None


class DataType(IntEnum):
    """The Sparkplug B datatypes edgedsm publishes or accepts in commands (spec, payloads: data types)."""

    INT8 = pb.Int8
    INT16 = pb.Int16
    INT32 = pb.Int32
    INT64 = pb.Int64
    UINT8 = pb.UInt8
    UINT16 = pb.UInt16
    UINT32 = pb.UInt32
    UINT64 = pb.UInt64
    FLOAT = pb.Float
    DOUBLE = pb.Double
    BOOLEAN = pb.Boolean
    STRING = pb.String
    DATETIME = pb.DateTime
    TEXT = pb.Text


_INT32_TYPES = {DataType.INT8, DataType.INT16, DataType.INT32, DataType.UINT8, DataType.UINT16, DataType.UINT32}
_INT64_TYPES = {DataType.INT64, DataType.UINT64, DataType.DATETIME}


class PayloadError(ValueError):
    """A payload that is not a usable Sparkplug B message (the reason in words)."""


@dataclass(frozen=True)
class Metric:
    """One metric as it goes out: on a birth with name, alias, datatype and unit; in data
    messages by alias only (spec: tck-id-payloads-alias-data-cmd-requirement)."""

    name: str
    datatype: DataType
    value: Value
    timestamp_ms: int
    alias: int | None = None
    unit: str | None = None


@dataclass(frozen=True)
class CommandMetric:
    """One metric of a received NCMD: what was written, to which name or alias."""

    name: str | None
    alias: int | None
    datatype: int | None
    value: Value
    value_kind: str | None  # the protobuf oneof field that carried it, e.g. "boolean_value"


def now_ms(wall_s: float) -> int:
    """UTC epoch milliseconds of a wall-clock time in seconds."""
    return round(wall_s * 1000.0)


def _set_value(target: pb.Payload.Metric, datatype: DataType, value: Value) -> None:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        target.is_null = True  # a null carries no value (tck-id-operational-behavior-data-publish-nbirth-values)
    elif datatype in _INT32_TYPES:
        target.int_value = int(value) & 0xFFFFFFFF  # signed types travel as two's complement
    elif datatype in _INT64_TYPES:
        target.long_value = int(value) & 0xFFFFFFFFFFFFFFFF
    elif datatype == DataType.FLOAT:
        target.float_value = float(value)
    elif datatype == DataType.DOUBLE:
        target.double_value = float(value)
    elif datatype == DataType.BOOLEAN:
        target.boolean_value = bool(value)
    else:
        target.string_value = str(value)


def encode(metrics: list[Metric], *, timestamp_ms: int, seq: int | None, birth: bool) -> bytes:
    """A Sparkplug B payload. Births carry name, alias (when given), datatype and unit; data
    messages carry the alias alone (the name only for a metric without alias). ``seq`` None:
    no sequence number (NDEATH)."""
    payload = pb.Payload(timestamp=timestamp_ms)
    if seq is not None:
        payload.seq = seq
    for metric in metrics:
        out = payload.metrics.add()
        if birth or metric.alias is None:
            out.name = metric.name
        if metric.alias is not None:
            out.alias = metric.alias
        if birth:
            out.datatype = int(metric.datatype)
            if metric.unit:
                out.properties.keys.append("engUnit")
                out.properties.values.add(type=pb.String, string_value=metric.unit)
        out.timestamp = metric.timestamp_ms
        _set_value(out, metric.datatype, metric.value)
    return payload.SerializeToString()


def _text(value: object) -> object:
    # proto2 strings are not checked for UTF-8 when parsed: invalid bytes come back as bytes
    return value.decode("utf-8", "replace") if isinstance(value, bytes) else value


def decode_command(data: bytes) -> list[CommandMetric]:
    """The metrics of an NCMD payload; PayloadError when it is not a Sparkplug B payload."""
    try:
        payload = pb.Payload.FromString(data)
    except DecodeError as exc:
        raise PayloadError(f"not a Sparkplug B protobuf payload ({exc})") from None
    if not payload.metrics:
        raise PayloadError("no metric in the command")
    metrics = []
    for metric in payload.metrics:
        kind = metric.WhichOneof("value")
        value: Value = None if kind is None or metric.is_null else _text(getattr(metric, kind))
        if not isinstance(value, bool | int | float | str | None):
            value = None  # datasets, templates: nothing edgedsm accepts
        metrics.append(CommandMetric(name=_text(metric.name) if metric.HasField("name") else None,
                                     alias=metric.alias if metric.HasField("alias") else None,
                                     datatype=metric.datatype if metric.HasField("datatype") else None,
                                     value=value, value_kind=kind))
    return metrics
