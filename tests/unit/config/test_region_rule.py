"""One rule for regions (issue 25 §2): `check-config`, the daemon's start and a reload accept and
refuse the same regions on the same frame, whatever the shape and the frame size."""

from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from edgedsm.config import DaemonConfig, check_regions, load_config
from edgedsm.daemon.measurement import Measurement
from edgedsm.daemon.reload import ReloadRefused, check_reload
from edgedsm.daemon.tau import TauRegions
from edgedsm.errors import ConfigError
from edgedsm.estimators.snapshot import MapBuffers
from edgedsm.frames import Frame
from edgedsm.validation import validate

coordinate = st.integers(-40, 100)
size = st.integers(1, 80)
regions = st.one_of(
    st.builds(lambda x, y, w, h: {"shape": "rect", "x": x, "y": y, "width": w, "height": h},
              coordinate, coordinate, size, size),
    st.builds(lambda cx, cy, r: {"shape": "circle", "cx": cx, "cy": cy, "radius": r}, coordinate, coordinate, size),
    st.builds(lambda cx, cy, r, w: {"shape": "ring", "cx": cx, "cy": cy, "inner_radius": r, "outer_radius": r + w},
              coordinate, coordinate, size, size),
)


def _config(region: dict[str, Any], tmp_path: Path) -> dict[str, Any]:
    return {"device": {"state_dir": str(tmp_path / "state")}, "camera": {"uri": "sim:default"},
            "estimator": {"window": 8, "lag": 1}, "regions": [{"name": "r", **region, "wet_above": 0.5,
                                                               "dry_below": 0.1}]}


def _refusal(call: Any) -> bool:
    try:
        call()
    except (ConfigError, ReloadRefused):
        return True
    return False


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(region=regions, rows=st.integers(8, 64), cols=st.integers(8, 64))
def test_check_config_start_and_reload_agree(tmp_path: Path, region: dict[str, Any], rows: int, cols: int) -> None:
    path = tmp_path / "daemon.toml"
    path.write_text(_toml(_config(region, tmp_path)), encoding="utf-8")
    config = load_config(path)  # the running camera: its frame is (rows, cols)
    frame = Frame(np.zeros((rows, cols), np.uint8), 0, 0, 8)

    checked = _refusal(lambda: check_regions(config, (rows, cols)))
    measurement = Measurement(config, TauRegions(config), MapBuffers(), Counter())
    started = _refusal(lambda: measurement.prepare(frame.format))
    reloaded = _refusal(lambda: check_reload(path, config, running_shape=(rows, cols)))
    assert checked == started == reloaded, (region, rows, cols, checked, started, reloaded)


def _toml(data: dict[str, Any]) -> str:
    region = data["regions"][0]
    lines = [f'[device]\nstate_dir = "{data["device"]["state_dir"]}"', '[camera]\nuri = "sim:default"',
             "[estimator]\nwindow = 8\nlag = 1", "[[regions]]"]
    lines += [f"{key} = {value!r}" if isinstance(value, str) else f"{key} = {value}" for key, value in region.items()]
    return "\n".join(lines).replace("'", '"') + "\n"


@pytest.mark.parametrize(("region", "refused"), [
    ({"shape": "rect", "x": 0, "y": 0, "width": 16, "height": 16}, False),
    ({"shape": "rect", "x": 20, "y": 0, "width": 16, "height": 16}, True),   # reaches outside: right
    ({"shape": "rect", "x": 40, "y": 40, "width": 4, "height": 4}, True),    # no pixel inside
])
def test_the_daemon_refuses_what_check_config_refuses(tmp_path: Path, region: dict[str, Any], refused: bool) -> None:
    config = validate(DaemonConfig, _config(region, tmp_path), "<test>")
    measurement = Measurement(config, TauRegions(config), MapBuffers(), Counter())
    assert _refusal(lambda: measurement.prepare(Frame(np.zeros((32, 32), np.uint8), 0, 0, 8).format)) is refused
