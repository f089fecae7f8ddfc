"""Region statistics without numba (maps, then masked moments) for a subset of the engine's maps."""

from __future__ import annotations

import numpy as np
import pytest

from edgedsm.estimators import SlidingWindow
from edgedsm.estimators.region_box import RegionBox
from edgedsm.estimators.region_stats import RegionPlan, _moments_from_maps


@pytest.mark.parametrize("mode", ["sliding", "tumbling", "exponential"])
@pytest.mark.parametrize("wanted", [("s1",), ("s2",), ("s3",), ("s1", "s3")])
def test_fallback_takes_any_subset_of_the_snapshots_maps(mode, wanted):
    """A snapshot of S1, S2, S3 asked for one of them: the maps kernel of the snapshot serves all
    three (a kernel for S1, S2, S3 writing into buffers sized for one map failed before)."""
    shape = (12, 10)
    frames = np.random.default_rng(4).integers(0, 256, (14, *shape), dtype=np.uint8)
    engine = SlidingWindow(shape, 7, 2, q=1.0, bits=8, mode=mode, kernel="numpy")
    for frame in frames:
        engine.push(frame)
    mask = np.zeros(shape, bool)
    mask[2:9, 3:8] = True
    plans = {"box": RegionPlan.of(RegionBox.of(mask), shape)}
    got = _moments_from_maps(engine.snapshot(live=True), plans, wanted, spread=True)["box"]
    maps = engine.maps()
    assert tuple(got) == wanted
    for key in wanted:
        values = maps[key][mask]
        assert got[key].pixels == 35
        assert got[key].mean == pytest.approx(float(values.mean()), rel=1e-12)
        assert got[key].std == pytest.approx(float(values.std()), rel=1e-9)
