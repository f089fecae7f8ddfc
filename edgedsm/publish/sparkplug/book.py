"""The metric book: every metric's alias, datatype, current value and last sent value, and
report-by-exception with a deadband (pure; the caller holds the lock and does the I/O).

A birth carries every metric (and marks them sent); a data message carries the metrics that
changed since they were last sent. A metric the last birth did not carry (new name, or a changed
datatype) makes :attr:`MetricBook.needs_birth` true: the spec allows metrics only in the birth
that announced them.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Mapping
from dataclasses import dataclass

from edgedsm.publish.sparkplug.metrics import Reading
from edgedsm.publish.sparkplug.payload import DataType, Metric, Value


@dataclass(frozen=True)
class Deadband:
    """A float is sent again when it moved by more than ``max(absolute, relative * |last sent|)``."""

    relative: float = 0.0
    absolute: float = 0.0

    def moved(self, sent: Value, value: Value) -> bool:
        if sent is None or value is None:
            return (sent is None) != (value is None)
        if isinstance(sent, float) and isinstance(value, float):  # finite: the book never keeps NaN
            return abs(value - sent) > max(self.absolute, self.relative * abs(sent))
        return sent != value


@dataclass
class _Entry:
    name: str
    alias: int | None
    reading: Reading
    t_ms: int | None = None  # when the value was measured (None: never set, a declared null)
    sent: Value = None
    born: bool = False  # carried by the latest birth


_FLOATS = {DataType.DOUBLE, DataType.FLOAT}


def _normalise(reading: Reading) -> Value:
    value = reading.value
    if reading.datatype in _FLOATS and value is not None:
        value = float(value)
        return value if math.isfinite(value) else None  # non-finite published as null
    return value


class MetricBook:
    """The metrics of one Sparkplug edge node or device. ``aliases`` hands out unique numbers
    (share one iterator between the node's and its devices' books: aliases must be unique
    across the whole edge node). ``no_alias`` names get none (spec: 'Node Control/Rebirth')."""

    def __init__(self, aliases: Iterator[int], deadband: Deadband, no_alias: frozenset[str] = frozenset()) -> None:
        self._aliases = aliases
        self.deadband = deadband
        self._no_alias = no_alias
        self._entries: dict[str, _Entry] = {}

    def __contains__(self, name: str) -> bool:
        return name in self._entries

    def __len__(self) -> int:
        return len(self._entries)

    def names(self) -> list[str]:
        """Every metric's name, in the order they were declared."""
        return list(self._entries)

    @property
    def needs_birth(self) -> bool:
        """A metric exists that the latest birth did not carry."""
        return any(not entry.born for entry in self._entries.values())

    def alias_of(self, name: str) -> int | None:
        entry = self._entries.get(name)
        return entry.alias if entry is not None else None

    def name_of(self, alias: int) -> str | None:
        return next((entry.name for entry in self._entries.values() if entry.alias == alias), None)

    def datatype_of(self, name: str) -> DataType | None:
        entry = self._entries.get(name)
        return entry.reading.datatype if entry is not None else None

    def value_of(self, name: str) -> Value:
        entry = self._entries.get(name)
        return _normalise(entry.reading) if entry is not None else None

    def declare(self, readings: Mapping[str, Reading]) -> None:
        """Add metrics not known yet (their values null or given), without a time of measurement."""
        for name, reading in readings.items():
            if name not in self._entries:
                self._entries[name] = _Entry(name, None if name in self._no_alias else next(self._aliases), reading)

    def update(self, readings: Mapping[str, Reading], t_ms: int) -> None:
        """Record new values measured at ``t_ms`` (UTC epoch ms)."""
        for name, reading in readings.items():
            entry = self._entries.get(name)
            if entry is None:
                alias = None if name in self._no_alias else next(self._aliases)
                entry = self._entries[name] = _Entry(name, alias, reading)
            elif entry.reading.datatype != reading.datatype or entry.reading.unit != reading.unit:
                entry.born = False  # hosts learn datatypes and units from births only
            entry.reading, entry.t_ms = reading, t_ms

    def _metric(self, entry: _Entry, t_ms: int) -> Metric:
        reading = entry.reading
        return Metric(name=entry.name, datatype=reading.datatype, value=_normalise(reading), timestamp_ms=t_ms,
                      alias=entry.alias, unit=reading.unit)

    def birth(self, now_ms: int) -> list[Metric]:
        """Every metric at its current value, in chronological order (spec:
        tck-id-operational-behavior-data-publish-dbirth-order); all marked sent."""
        metrics = []
        for entry in self._entries.values():
            entry.born, entry.sent = True, _normalise(entry.reading)
            metrics.append(self._metric(entry, entry.t_ms if entry.t_ms is not None else now_ms))
        return sorted(metrics, key=lambda metric: metric.timestamp_ms)

    def changes(self) -> list[Metric]:
        """The born metrics whose value moved (beyond the deadband for floats) since last sent,
        in chronological order; marked sent. Metrics not yet born wait for the next birth."""
        metrics = []
        for entry in self._entries.values():
            value = _normalise(entry.reading)
            if entry.born and self.deadband.moved(entry.sent, value):
                entry.sent = value
                metrics.append(self._metric(entry, entry.t_ms if entry.t_ms is not None else 0))
        return sorted(metrics, key=lambda metric: metric.timestamp_ms)
