"""An independent Sparkplug B payload decoder for the tests: a protobuf wire-format reader written
from the field numbers of the spec's schema (Sparkplug 3.0, chapter 6 / Tahu sparkplug_b.proto),
sharing no code with edgedsm's encoder (which uses the generated protobuf classes). What edgedsm
publishes is checked through this reader, so an encoder mistake cannot cancel out."""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import Any

#: Sparkplug B datatype numbers (spec: payloads, data types).
DATATYPES = {1: "Int8", 2: "Int16", 3: "Int32", 4: "Int64", 5: "UInt8", 6: "UInt16", 7: "UInt32", 8: "UInt64",
             9: "Float", 10: "Double", 11: "Boolean", 12: "String", 13: "DateTime", 14: "Text"}


def _varint(data: bytes, pos: int) -> tuple[int, int]:
    result = shift = 0
    while True:
        byte = data[pos]
        pos += 1
        result |= (byte & 0x7F) << shift
        if not byte & 0x80:
            return result, pos
        shift += 7


def fields(data: bytes) -> list[tuple[int, int, Any]]:
    """(field number, wire type, raw value) of each field of one message."""
    out, pos = [], 0
    while pos < len(data):
        key, pos = _varint(data, pos)
        number, wire = key >> 3, key & 7
        if wire == 0:
            value, pos = _varint(data, pos)
        elif wire == 1:
            value, pos = data[pos:pos + 8], pos + 8
        elif wire == 2:
            length, pos = _varint(data, pos)
            value, pos = data[pos:pos + length], pos + length
        elif wire == 5:
            value, pos = data[pos:pos + 4], pos + 4
        else:
            raise ValueError(f"wire type {wire} not used by Sparkplug B")
        out.append((number, wire, value))
    return out


@dataclass
class DecodedMetric:
    name: str | None = None
    alias: int | None = None
    timestamp: int | None = None
    datatype: int | None = None
    is_null: bool = False
    value_field: str | None = None  # which oneof field carried the value
    raw: Any = None
    properties: dict[str, Any] = field(default_factory=dict)

    @property
    def datatype_name(self) -> str | None:
        return DATATYPES.get(self.datatype) if self.datatype is not None else None

    def value(self, datatype: int | None = None) -> Any:
        """The value interpreted with ``datatype`` (default: this metric's own; data messages carry none)."""
        kind = DATATYPES.get(datatype if datatype is not None else self.datatype or 0)
        if self.is_null or self.value_field is None:
            return None
        if self.value_field == "int_value":
            return self.raw - (1 << 32) if kind in ("Int8", "Int16", "Int32") and self.raw >= 1 << 31 else self.raw
        if self.value_field == "long_value":
            return self.raw - (1 << 64) if kind == "Int64" and self.raw >= 1 << 63 else self.raw
        return self.raw


@dataclass
class DecodedPayload:
    timestamp: int | None = None
    seq: int | None = None
    metrics: list[DecodedMetric] = field(default_factory=list)

    def by_name(self) -> dict[str, DecodedMetric]:
        return {metric.name: metric for metric in self.metrics if metric.name is not None}


def _properties(data: bytes) -> dict[str, Any]:
    keys, values = [], []
    for number, _, raw in fields(data):
        if number == 1:
            keys.append(raw.decode("utf-8"))
        elif number == 2:
            value = None
            for sub, _, sub_raw in fields(raw):
                if sub == 8:
                    value = sub_raw.decode("utf-8")
                elif sub in (3, 4):
                    value = sub_raw
            values.append(value)
    assert len(keys) == len(values), "PropertySet: keys and values differ in number"
    return dict(zip(keys, values, strict=True))


def _metric(data: bytes) -> DecodedMetric:
    metric = DecodedMetric()
    for number, _, raw in fields(data):
        if number == 1:
            metric.name = raw.decode("utf-8")
        elif number == 2:
            metric.alias = raw
        elif number == 3:
            metric.timestamp = raw
        elif number == 4:
            metric.datatype = raw
        elif number == 7:
            metric.is_null = bool(raw)
        elif number == 9:
            metric.properties = _properties(raw)
        elif number == 10:
            metric.value_field, metric.raw = "int_value", raw
        elif number == 11:
            metric.value_field, metric.raw = "long_value", raw
        elif number == 12:
            metric.value_field, metric.raw = "float_value", struct.unpack("<f", raw)[0]
        elif number == 13:
            metric.value_field, metric.raw = "double_value", struct.unpack("<d", raw)[0]
        elif number == 14:
            metric.value_field, metric.raw = "boolean_value", bool(raw)
        elif number == 15:
            metric.value_field, metric.raw = "string_value", raw.decode("utf-8")
    return metric


def decode(data: bytes) -> DecodedPayload:
    """A Sparkplug B Payload message."""
    payload = DecodedPayload()
    for number, _, raw in fields(data):
        if number == 1:
            payload.timestamp = raw
        elif number == 2:
            payload.metrics.append(_metric(raw))
        elif number == 3:
            payload.seq = raw
    return payload


def key(number: int, wire: int) -> bytes:
    return encode_varint(number << 3 | wire)


def encode_varint(value: int) -> bytes:
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        out.append(byte | (0x80 if value else 0))
        if not value:
            return bytes(out)


def length_delimited(number: int, data: bytes) -> bytes:
    return key(number, 2) + encode_varint(len(data)) + data


def command(metrics: list[dict[str, Any]], timestamp: int = 1) -> bytes:
    """An NCMD payload written by hand on the wire, as a host would send it: each metric a dict
    with ``name`` / ``alias`` / ``datatype`` and one of ``boolean_value``, ``int_value``,
    ``long_value``, ``string_value``."""
    body = key(1, 0) + encode_varint(timestamp)
    for metric in metrics:
        part = b""
        if "name" in metric:
            part += length_delimited(1, metric["name"].encode("utf-8"))
        if "alias" in metric:
            part += key(2, 0) + encode_varint(metric["alias"])
        if "datatype" in metric:
            part += key(4, 0) + encode_varint(metric["datatype"])
        if "boolean_value" in metric:
            part += key(14, 0) + encode_varint(int(metric["boolean_value"]))
        if "int_value" in metric:
            part += key(10, 0) + encode_varint(metric["int_value"])
        if "long_value" in metric:
            part += key(11, 0) + encode_varint(metric["long_value"])
        if "string_value" in metric:
            part += length_delimited(15, metric["string_value"].encode("utf-8"))
        body += length_delimited(2, part)
    return body
