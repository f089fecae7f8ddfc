"""Each map's unit and label as the sinks show them, from the estimators' registry
(``edgedsm.estimators.registry``, the one place they are kept): Prometheus labels, Home
Assistant's ``unit_of_measurement`` and names, the dashboard's columns and axis."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from edgedsm.estimators.registry import Record

#: The unit of a map the registry does not know (a newer daemon's): shown, never guessed.
UNKNOWN = "?"


def _record(name: str) -> Record | None:
    from edgedsm.estimators import registry  # `edgedsm cmd` and `watch` start without the estimators

    try:
        return registry.get(name)
    except KeyError:
        return None


def unit_of(name: str) -> str:
    """The unit of map ``name`` (``"1"``: dimensionless; ``"s"`` for τc), ``"?"`` when unknown."""
    record = _record(name)
    return record.unit if record is not None else UNKNOWN


def label_of(name: str) -> str:
    """The short label of map ``name`` (``"S2"``, ``"τc"``, ``"contrast"``); its name upper-cased
    when the registry does not know it."""
    record = _record(name)
    return record.label if record is not None else name.upper()


def display_unit(unit: str) -> str | None:
    """``unit`` for a reader: None for a dimensionless value (``"1"``, ``"1 (0..200)"``), which
    Home Assistant and the page show as a bare number."""
    return None if unit == "1" or unit.startswith("1 (") else unit
