"""Typed options of device URIs (``?key=value&...``), shared by the camera and relay schemes.

Every error is a ConfigError that names the URI and the offending option.
"""

from __future__ import annotations

import math
from urllib.parse import parse_qsl

from edgedsm.errors import ConfigError


class UriOptions:
    """Converts the option texts of one URI; ``kind`` ("camera", "relay") prefixes the errors."""

    def __init__(self, kind: str, uri: str) -> None:
        self.prefix = f"{kind} URI {uri!r}"

    def fail(self, reason: str) -> ConfigError:
        return ConfigError(f"{self.prefix}: {reason}")

    def split(self, query: str, allowed: set[str], scheme: str = "") -> dict[str, str]:
        """``a=1&b=2`` as a dict, strictly: no empty values, no repeats, only ``allowed`` keys."""
        if not query:
            return {}
        try:
            pairs = parse_qsl(query, keep_blank_values=True, strict_parsing=True)
        except ValueError:
            raise self.fail(f"cannot read the options {query!r}: expected key=value&key=value") from None
        options: dict[str, str] = {}
        for key, value in pairs:
            if key in options:
                raise self.fail(f"option {key!r} is given twice")
            if key not in allowed:
                where = f" for {scheme}" if scheme else ""
                raise self.fail(f"unknown option {key!r}{where} (known: {', '.join(sorted(allowed))})")
            if value == "":
                raise self.fail(f"option {key!r} has no value")
            options[key] = value
        return options

    def integer(self, key: str, text: str, low: int, high: int) -> int:
        try:
            value = int(text, 10)
        except ValueError:
            raise self.fail(f"{key}={text!r} is not a whole number") from None
        if not low <= value <= high:
            raise self.fail(f"{key}={value} is out of range {low}..{high}")
        return value

    def number(self, key: str, text: str, low: float, high: float = math.inf, open_low: bool = False,
               unit: str = "") -> float:
        try:
            value = float(text)
        except ValueError:
            raise self.fail(f"{key}={text!r} is not a number") from None
        if not (low < value if open_low else low <= value) or not value <= high:  # also refuses nan
            bound = f"> {low:g}" if open_low else f">= {low:g}"
            upper = f" and <= {high:g}" if high < math.inf else ""
            raise self.fail(f"{key}={text} must be {bound}{upper}{(' ' + unit) if unit else ''}")
        return value

    def boolean(self, key: str, text: str) -> bool:
        lowered = text.lower()
        if lowered in ("true", "1", "yes", "on"):
            return True
        if lowered in ("false", "0", "no", "off"):
            return False
        raise self.fail(f"{key}={text!r} must be true or false")
