"""The daemon's kernels come from numba's disk cache at the next start (a defect of issue 13's
first region kernels, and of the τc lag-product kernels: closures over other compiled closures
got a new cache key in every process, so each start compiled them again, 7-10 s before the first
frame). Two real processes run the evaluation's warm-up on the same settings; the second must
compile nothing."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from edgedsm.config import DaemonConfig
from edgedsm.daemon import engine_budget
from edgedsm.daemon.engine_budget import kernel_variants
from edgedsm.daemon.pipeline import Pipeline
from edgedsm.devices.camera import SimulatedCamera
from edgedsm.publish.sink import RecordingSink
from edgedsm.sim import load_scene
from edgedsm.validation import validate
from tests.kernel_cache import ESTIMATORS, REPO, warm_start

SCENE = REPO / "config" / "scenes" / "drying_demo.toml"


@pytest.mark.slow
@pytest.mark.parametrize(("estimator", "frame_shape"), ESTIMATORS,
                         ids=["default", "tumbling-tau", "sliding-tau", "exponential"])
def test_the_second_start_compiles_nothing(estimator: dict, frame_shape: tuple[int, int] | None) -> None:
    warm_start(estimator, frame_shape)  # compiles what is not cached yet
    assert warm_start(estimator, frame_shape) == []


VARIANTS = r"""
import numpy as np
from edgedsm.estimators.kernels_numba import maps_kernel
n = 64
sums = [np.ones(n, np.int32)] * 5
out = [np.empty(n) for _ in range(7)]
for parallel in (False, True):  # the serial variant compiled (and cached) first, as the warm-up does
    kernel = maps_kernel(True, True, True, parallel)
    kernel(*sums, 3, 0.5, 4, *out, 1.0)
    print(kernel.stats.cache_hits.total(), kernel.targetoptions.get("parallel", False))
"""


@pytest.mark.slow
def test_parallel_and_serial_variants_are_cached_apart(tmp_path: Path) -> None:
    """numba's cache key leaves out the decorator's options: without kernel_variant the parallel
    kernel loaded the serial one's code from the cache (found: 4x slower region statistics)."""
    done = subprocess.run([sys.executable, "-c", VARIANTS], capture_output=True, text=True, timeout=240,
                          env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["0", "False", "0", "True"]  # each compiled, none loaded the other's code


def _config(**estimator) -> DaemonConfig:
    data = {"camera": {"uri": f"sim:{SCENE}"}, "acquisition": {"dark_frames": 0},
            "estimator": {"window": 40, "lag": 3, **estimator},
            "regions": [{"name": "plate", "shape": "rect", "x": 4, "y": 4, "width": 20, "height": 20,
                         "wet_above": 1.0, "dry_below": 0.5}]}
    return validate(DaemonConfig, data, "<warm-up>")


def test_the_warm_up_loads_the_kernel_variants_that_size_of_frame_runs() -> None:
    frame = _config()
    cropped = _config(area="regions")
    assert kernel_variants(frame, None) == kernel_variants(cropped, None) == (False, True)  # not known yet
    assert kernel_variants(frame, (128, 128)) == kernel_variants(cropped, (128, 128)) == (False,)
    assert kernel_variants(frame, (256, 256)) == (True,)  # 65,536 pixels: PARALLEL_MIN_PIXELS
    assert kernel_variants(frame, (255, 256)) == (False,)
    assert kernel_variants(cropped, (2048, 2048)) == (False, True)  # the regions' box may be small


def test_a_daemon_warms_up_for_the_frames_its_camera_says_it_delivers(monkeypatch) -> None:
    """The pipeline asks the open camera its frame size before frames flow (a 128² simulated camera:
    only the serial kernels); a camera that cannot say gets both variants."""
    loaded: list[bool] = []
    monkeypatch.setattr(engine_budget, "_warm_up", lambda config, parallel: loaded.append(parallel))
    config = _config()
    for camera, expected in ((SimulatedCamera(load_scene(SCENE), time_scale=0), [False]),
                             (SizeUnknownCamera(load_scene(SCENE), time_scale=0), [False, True])):
        loaded.clear()
        Pipeline(config, camera, RecordingSink()).run(lambda: True)
        assert loaded == expected, camera
        assert not camera.is_open


class SizeUnknownCamera(SimulatedCamera):
    """A camera that cannot tell its frame size before a frame comes."""

    def _do_frame_format(self) -> None:
        return None


def test_a_warm_up_that_fails_closes_the_camera(monkeypatch) -> None:
    def broken(config, parallel):
        raise MemoryError("no room for the warm-up engine")

    monkeypatch.setattr(engine_budget, "_warm_up", broken)
    camera = SimulatedCamera(load_scene(SCENE), time_scale=0)
    with pytest.raises(MemoryError, match="warm-up engine"):
        Pipeline(_config(), camera, RecordingSink()).run(lambda: True)
    assert not camera.is_open
