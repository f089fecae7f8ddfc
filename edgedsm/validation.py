"""Reading and validating TOML input (daemon configs, scene files): bounded, strict, and every
problem turned into a ConfigError message that names the key path."""

from __future__ import annotations

import datetime
import json
import os
import re
import stat
import tomllib
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel, ConfigDict, ValidationError

from edgedsm.errors import ConfigError

#: Largest config or scene file read; real ones are a few kB (a bound, so /dev/zero cannot hang us).
MAX_FILE_BYTES = 1 << 20
#: Deepest nesting of tables and arrays accepted (the deepest real key path has 4 levels).
MAX_NESTING = 32

ModelT = TypeVar("ModelT", bound=BaseModel)
_BARE_KEY = re.compile(r"^[A-Za-z0-9_-]+$")


class StrictModel(BaseModel):
    """Base of every config model: unknown keys refused, values validated on assignment,
    numbers finite (TOML has ``nan`` and ``inf``)."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True, frozen=False, allow_inf_nan=False)


def same_settings(a: Any, b: Any) -> bool:
    """Whether two config values (a model, a list of models, None) hold the same settings.

    Only the fields count: pydantic's ``==`` also compares private attributes, and a section
    caches what it derived (a parsed URI) in them once used, so a running section never equals
    the same section read again from the same file.
    """
    if isinstance(a, BaseModel) or isinstance(b, BaseModel):
        return type(a) is type(b) and a.model_dump() == b.model_dump()
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same_settings(x, y) for x, y in zip(a, b, strict=True))
    return a == b


def format_validation_error(error: ValidationError, source: str, data: Any = None) -> str:
    """One line per problem: ``source: key.path: reason``."""
    lines = []
    for item in error.errors():
        path = ".".join(_key_name(part) for part in _key_path(item["loc"], data))
        reason = item["msg"]
        if item["type"] == "extra_forbidden":
            reason = "unknown key (not allowed here; check the spelling)"
        lines.append(f"{source}: {path or '<top level>'}: {reason}")
    return "\n".join(lines)


def _key_name(part: Any) -> str:
    # a key TOML would need quotes for (empty, spaces, dots, control characters) is shown quoted
    text = str(part)
    return text if isinstance(part, int) or _BARE_KEY.match(text) else json.dumps(text)


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
    """Read a TOML file: a regular file of at most MAX_FILE_BYTES of UTF-8, nested at most
    MAX_NESTING deep. Every problem is a one-line ConfigError naming the file."""
    text = _read_text(path)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    except RecursionError:
        raise ConfigError(f"{path}: nested more than {MAX_NESTING} levels deep") from None
    _check_nesting(data, path)
    return data


def _read_text(path: Path) -> str:
    try:
        # stat before open: opening a FIFO would block, reading a device would never end
        mode = os.stat(path).st_mode
        if not stat.S_ISREG(mode):
            raise ConfigError(f"{path}: not a regular file")
        with open(path, "rb") as handle:
            raw = handle.read(MAX_FILE_BYTES + 1)
    except FileNotFoundError:
        raise ConfigError(f"{path}: file not found") from None
    except OSError as exc:
        raise ConfigError(f"{path}: cannot be read: {exc.strerror}") from None
    if len(raw) > MAX_FILE_BYTES:
        raise ConfigError(f"{path}: larger than {MAX_FILE_BYTES // 1024} KiB; not a configuration file")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b"\n") + 1
        raise ConfigError(f"{path}: not UTF-8 text (byte 0x{raw[exc.start]:02x} at line {line})") from None


def _check_nesting(data: Any, path: Path) -> None:
    """Iterative, so the check itself cannot overflow the stack."""
    pending = [(data, 1)]
    while pending:
        node, depth = pending.pop()
        if depth > MAX_NESTING:
            raise ConfigError(f"{path}: nested more than {MAX_NESTING} levels deep")
        children = node.values() if isinstance(node, dict) else node if isinstance(node, list) else ()
        pending.extend((child, depth + 1) for child in children if isinstance(child, dict | list))


def validate(model: type[ModelT], data: dict[str, Any], source: str, context: dict | None = None) -> ModelT:
    """Validate ``data`` (as read from TOML) against ``model`` strictly: a string is never taken
    for a number or a boolean, nor a number for a boolean. ConfigError lists every problem with
    its key path.

    The data goes through pydantic's JSON mode, whose strict rules are the ones a text file
    needs (a path or a tuple may come as a string or an array; an int is a valid float).
    """
    _refuse_nul(data, source)
    try:
        document = json.dumps(data, default=_json_default, allow_nan=True)
    except (TypeError, ValueError, RecursionError) as exc:
        raise ConfigError(f"{source}: cannot be validated: {exc}") from None
    try:
        return model.model_validate_json(document, strict=True, context=context)
    except ValidationError as exc:
        raise ConfigError(format_validation_error(exc, source, data)) from None


def _refuse_nul(data: Any, source: str) -> None:
    """A NUL character cannot be in a path, a URI or a name handed to the system: refuse it with
    its key path here (pydantic would accept it and the OS call fail later)."""
    pending: list[tuple[Any, tuple]] = [(data, ())]
    while pending:
        node, path = pending.pop()
        items = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
        for key, value in items:
            where = (*path, key)
            if (isinstance(key, str) and "\x00" in key) or (isinstance(value, str) and "\x00" in value):
                name = ".".join(_key_name(part) for part in where)
                raise ConfigError(f"{source}: {name}: contains a NUL character")
            pending.append((value, where))


def _json_default(value: Any) -> Any:
    # TOML dates and times have no JSON form; no field takes one, so they must fail as themselves
    if isinstance(value, datetime.date | datetime.time):
        return {"toml date/time": value.isoformat()}
    if isinstance(value, Path):  # scenes built in code
        return str(value)
    if hasattr(value, "item"):  # numpy scalars from code
        return value.item()
    raise TypeError(f"unexpected value {value!r}")
