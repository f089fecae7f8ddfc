"""Turn pydantic validation errors into ConfigError messages that name the key path."""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel, ConfigDict, ValidationError

from edgedsm.errors import ConfigError

ModelT = TypeVar("ModelT", bound=BaseModel)


class StrictModel(BaseModel):
    """Base of every config model: unknown keys refused, values validated on assignment."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True, frozen=False)


def format_validation_error(error: ValidationError, source: str, data: Any = None) -> str:
    """One line per problem: ``source: key.path: reason``."""
    lines = []
    for item in error.errors():
        path = ".".join(str(part) for part in _key_path(item["loc"], data))
        reason = item["msg"]
        if item["type"] == "extra_forbidden":
            reason = "unknown key (not allowed here; check the spelling)"
        lines.append(f"{source}: {path or '<top level>'}: {reason}")
    return "\n".join(lines)


def _key_path(loc: tuple, data: Any) -> list:
    """The location as the user wrote it: pydantic inserts the tag of a discriminated union
    ("rect", "circle"...) into the location; it is dropped where the input has no such key
    but carries it as a value."""
    path, node = [], data
    for part in loc:
        if isinstance(node, dict) and isinstance(part, str) and part not in node and part in node.values():
            continue
        path.append(part)
        try:
            node = node[part]
        except (KeyError, IndexError, TypeError):
            node = None
    return path


def read_toml(path: Path) -> dict[str, Any]:
    """Read a TOML file, mapping I/O and syntax problems to ConfigError."""
    try:
        with open(path, "rb") as handle:
            return tomllib.load(handle)
    except FileNotFoundError:
        raise ConfigError(f"{path}: file not found") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot be read: {exc.strerror}") from None


def validate(model: type[ModelT], data: dict[str, Any], source: str) -> ModelT:
    """Validate ``data`` against ``model``; ConfigError lists every problem with its key path."""
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(format_validation_error(exc, source, data)) from None
