"""JSON encoding for published payloads: numpy values made plain, non-finite floats as null."""

from __future__ import annotations

import enum
import json
import math
from collections.abc import Mapping
from datetime import datetime
from pathlib import PurePath
from typing import Any

import numpy as np


def jsonable(value: Any) -> Any:
    """A structure json.dumps accepts: numpy scalars and arrays become Python numbers and lists,
    NaN and inf become None (JSON has no such numbers and strict parsers reject them)."""
    if isinstance(value, Mapping):
        return {str(key): jsonable(item) for key, item in value.items()}
    if isinstance(value, list | tuple | set | frozenset):
        return [jsonable(item) for item in value]
    if isinstance(value, np.ndarray):
        return jsonable(value.tolist())
    if isinstance(value, np.generic):
        return jsonable(value.item())
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, enum.Enum):
        return jsonable(value.value)
    if isinstance(value, datetime):
        return value.isoformat()
    if isinstance(value, PurePath):
        return str(value)
    return value


def dumps(value: Any) -> bytes:
    """Compact UTF-8 JSON of ``jsonable(value)``; TypeError for values with no JSON form."""
    return json.dumps(jsonable(value), separators=(",", ":"), allow_nan=False,
                      ensure_ascii=False).encode("utf-8")
