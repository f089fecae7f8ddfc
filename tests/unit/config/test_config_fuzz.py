"""Fuzzing the configuration (hypothesis): random bytes, random TOML documents and random values
for every field give either a valid config or a ConfigError whose lines name a key path — never
another exception — through ``load_config`` and through ``edgedsm check-config`` in-process."""

from __future__ import annotations

import datetime
import json
import os
import re
import tempfile
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import BaseModel

from edgedsm.cli import main
from edgedsm.config import DaemonConfig, RegionSettings, check_regions, load_config
from edgedsm.devices.camera.uri import known_frame_shape
from edgedsm.errors import ConfigError
from edgedsm.geometry import Circle, Mask, Polygon, Rect, Ring, Text

#: EDGEDSM_FUZZ_EXAMPLES=5000 for a longer hunt than the test suite's
EXAMPLES = int(os.environ.get("EDGEDSM_FUZZ_EXAMPLES", "120"))
FUZZ = settings(max_examples=EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow])

BASE: dict[str, Any] = {
    "device": {"name": "fuzz", "state_dir": "state"},
    "camera": {"uri": "sim:default"},
    "laser": {"uri": "sim:fuzz"},
    "acquisition": {"dark_frames": 5},
    "estimator": {"window": 100, "lag": 5},
    "regions": [{"name": "plate", "shape": "rect", "x": 1, "y": 2, "width": 30, "height": 40,
                 "wet_above": 0.3, "dry_below": 0.16}],
    "mqtt": {"host": "127.0.0.1", "port": 1883},
    "logging": {"level": "info"},
}


def _fields(model: type[BaseModel]) -> list[str]:
    return list(model.model_fields)


SECTION_KEYS = {name: _fields(field.annotation) for name, field in DaemonConfig.model_fields.items()  # type: ignore[arg-type]
                if isinstance(field.annotation, type) and issubclass(field.annotation, BaseModel)}
SECTION_KEYS.update({"laser": ["uri"], "mqtt": ["host", "port", "username", "keepalive_s", "topic_prefix", "qos",
                                                "stats_interval_s", "maps_interval_s", "tls"]})
REGION_KEYS = sorted({key for model in (RegionSettings, Rect, Circle, Ring, Polygon, Text, Mask)
                      for key in model.model_fields})
ALL_KEYS = sorted({*SECTION_KEYS, "regions", *REGION_KEYS, *(k for keys in SECTION_KEYS.values() for k in keys)})

# -- TOML values and documents -------------------------------------------------------------------

text = st.text(st.characters(exclude_categories=("Cs",)), max_size=12)
scalars = st.one_of(
    st.integers(-(2**63), 2**63 - 1), st.floats(allow_nan=True, allow_infinity=True), st.booleans(), text,
    st.sampled_from(["sim:default", "sim:", "replay:x.npy", "aravis:", "v4l2:0", "full", "rect", "polygon",
                     "mask", "s2", "bursts", "serial:/dev/ttyUSB0?protocol=lcus", "/dev/zero", "..", "a\x00b",
                     "replay:/dev/zero", "replay:a\x00b", "sim:/dev/zero", "sim:a\x00b", "sim:/", "replay:/",
                     "sim:.", "replay:..", "v4l2:0?width=64&height=48", "aravis:Fake_1?buffers=2"]),
    st.datetimes(min_value=datetime.datetime(1, 1, 1), max_value=datetime.datetime(9999, 1, 1)),
    st.dates(), st.times(),
)
keys = st.one_of(st.sampled_from(ALL_KEYS), text.filter(bool))
values = st.recursive(scalars, lambda children: st.one_of(
    st.lists(children, max_size=4), st.dictionaries(keys, children, max_size=4)), max_leaves=12)


def toml_value(value: Any) -> str:
    """A value as inline TOML (every tree of TOML values has an inline form)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if value != value:
            return "nan"
        if value in (float("inf"), float("-inf")):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)  # a JSON string without surrogates is a TOML basic string
    if isinstance(value, datetime.datetime | datetime.date | datetime.time):
        return value.isoformat()
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(item) for item in value) + "]"
    return "{" + ", ".join(f"{json.dumps(k)} = {toml_value(v)}" for k, v in value.items()) + "}"


def toml_document(data: dict[str, Any]) -> str:
    return "".join(f"{json.dumps(key)} = {toml_value(value)}\n" for key, value in data.items())


# -- the property ---------------------------------------------------------------------------------

LINE = re.compile(r"^(?P<source>.+?\.toml): (?P<path>\S+): \S.*$")


def check_outcome(content: bytes, expected_paths: tuple[str, ...] = ()) -> None:
    """load_config (with check_regions where the frame size is known) and check-config agree:
    a config, or a ConfigError naming key paths."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "fuzz.toml"
        path.write_bytes(content)
        try:
            config = load_config(path)
            valid = True
            shape = known_frame_shape(config.camera.spec)
            if shape is not None:  # check-config also checks the regions against the frame
                check_regions(config, shape)
        except ConfigError as exc:
            valid = False
            lines = str(exc).splitlines()
            assert lines, "an empty ConfigError"
            for line in lines:
                assert line.startswith(str(path)), line
                match = LINE.match(line)
                if match and expected_paths:  # an error of the document itself has no key path
                    key_path = match["path"]
                    assert key_path == "<top level>" or key_path.startswith(expected_paths), (key_path, line)
        code = _check_config(path)
        assert code == (0 if valid else 78)


def _check_config(path: Path) -> int:
    import contextlib
    import io

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(["check-config", str(path)])
    assert "Traceback" not in err.getvalue()
    return code


@FUZZ
@given(st.binary(max_size=400))
def test_random_bytes(content):
    check_outcome(content)


@FUZZ
@given(st.dictionaries(keys, values, max_size=6))
def test_random_toml_documents(document):
    check_outcome(toml_document(document).encode())


FIELDS = [(section, key) for section, section_keys in SECTION_KEYS.items() for key in section_keys] + [
    ("regions", key) for key in REGION_KEYS]


@settings(FUZZ, max_examples=EXAMPLES * 5 // 2)
@given(st.sampled_from(FIELDS), st.one_of(scalars, values))
def test_random_value_for_each_field(field, value):
    section, key = field
    data = json.loads(json.dumps(BASE))
    if section == "regions":
        data["regions"][0][key] = value
        expected = ("regions.0",)
    else:
        data.setdefault(section, {})[key] = value
        expected = (section,)
    check_outcome(toml_document(data).encode(), expected)


@pytest.mark.parametrize("section", sorted(SECTION_KEYS))
def test_the_base_document_is_valid_and_every_section_is_fuzzed(section):
    assert SECTION_KEYS[section], section
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "base.toml"
        path.write_text(toml_document(BASE))
        load_config(path)
