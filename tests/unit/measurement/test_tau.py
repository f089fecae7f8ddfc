"""τc of the regions and the τc map in seconds (edgedsm/measurement/tau.py): the one computation
the daemon's evaluator, the timeline and tune publish. On the same window it equals the batch
reference and the engine's own region fit, in both window modes; the daemon's TauRegions hands it
the region pixels and returns the same values; the block map reads a two-level scene."""

from __future__ import annotations

import numpy as np
import pytest

from edgedsm.config import DaemonConfig
from edgedsm.daemon.tau import TauRegions
from edgedsm.estimators import SlidingWindow, tau_c
from edgedsm.estimators.correlation_time import MEASURED
from edgedsm.measurement.tau import STATUS_NAMES, in_seconds, map_block, map_seconds, region_fits, region_taus
from edgedsm.validation import validate
from tests.unit.estimators.test_tau_pooled import LAG, MAX_LAG, SIZE, _frames, _snapshot


def _halves() -> dict[str, np.ndarray]:
    right = np.zeros((SIZE, SIZE), bool)
    right[:, SIZE // 2:] = True  # τc 5 frames; the left half 10 (the bound K = 8: "above")
    return {"right": right, "left": ~right}


@pytest.mark.parametrize("mode", ["sliding", "tumbling"])
def test_a_regions_tau_is_the_batch_reference_and_the_engines_own_fit(mode: str) -> None:
    window = 60
    frames = _frames(window + 23)
    engine = SlidingWindow((SIZE, SIZE), window=window, lag=LAG, estimators=("s1", "tau_c"), mode=mode,
                           max_lag=MAX_LAG)
    for frame in frames:
        engine.push(np.ascontiguousarray(frame))
    masks = _halves()
    fits = region_fits(engine.tau_snapshot(), {name: np.flatnonzero(mask) for name, mask in masks.items()})
    last = frames[(len(frames) // window) * window - window:(len(frames) // window) * window] if mode == "tumbling" \
        else frames[-window:]  # the tumbling engine reads its last complete set
    for name, mask in masks.items():
        own = engine.region_tau_c(mask)  # the engine's numpy covariances, pooled, then fitted
        assert int(fits[name].status) == int(own.status), name
        assert float(fits[name].tau) == pytest.approx(float(own.tau), rel=1e-12), name
        assert float(fits[name].tau) == pytest.approx(tau_c(last, max_lag=MAX_LAG, mask=mask), rel=1e-9), name
    assert int(fits["right"].status) == MEASURED and STATUS_NAMES[int(fits["left"].status)] == "above"


def test_in_seconds_is_the_fit_times_the_interval() -> None:
    snapshot, _ = _snapshot("sliding")
    pixels = {name: np.flatnonzero(mask) for name, mask in _halves().items()}
    fits = region_fits(snapshot, pixels)
    taus = region_taus(snapshot, pixels, 0.5)
    for name, fit in fits.items():
        assert taus[name] == in_seconds(fit, 0.5)
        assert taus[name].tau_c_s == float(fit.tau) * 0.5 and taus[name].status == STATUS_NAMES[int(fit.status)]
    assert taus["right"].status == "measured" and taus["right"].tau_c_s == pytest.approx(2.5, rel=0.3)


def test_the_daemon_hands_the_core_its_pixels_and_publishes_its_values() -> None:
    snapshot, frames = _snapshot("sliding")
    config = validate(DaemonConfig, {"camera": {"uri": "sim:default"}, "estimator": {"tau_c": True}}, "<tau>")
    regions = TauRegions(config)
    regions.pixels = {name: np.flatnonzero(mask) for name, mask in _halves().items()}
    got = regions.regions(snapshot, interval_s=0.5)
    assert got == region_taus(snapshot, regions.pixels, 0.5)
    assert regions.status == {"right": "measured", "left": "above"}
    only = regions.regions(snapshot, interval_s=0.5, names={"right"})
    assert set(only) == {"right"} and only["right"] == got["right"]
    expected = tau_c(frames[-snapshot.window:], max_lag=MAX_LAG, mask=_halves()["right"])
    assert got["right"].tau_c_s == pytest.approx(expected * 0.5, rel=1e-9)


def test_the_block_map_reads_each_half_of_a_two_level_scene() -> None:
    window = 400
    frames = _frames(window + 5, tau=3.0)  # τc 6 frames on the left half, 3 on the right
    engine = SlidingWindow((SIZE, SIZE), window=window, lag=LAG, estimators=("tau_c",), max_lag=MAX_LAG)
    for frame in frames:
        engine.push(np.ascontiguousarray(frame))
    seconds = map_seconds(engine.tau_snapshot(), interval_s=0.1, block=5)
    assert seconds.shape == (SIZE, SIZE) and np.all(np.isfinite(seconds))
    assert np.all(seconds[5:10, :5] == seconds[5, 0])  # one value per block
    left, right = np.median(seconds[10:, :SIZE // 2 - 5]), np.median(seconds[10:, SIZE // 2 + 5:])
    assert left == pytest.approx(0.6, rel=0.2) and right == pytest.approx(0.3, rel=0.2)
    per_pixel = map_seconds(engine.tau_snapshot(), interval_s=0.1)
    np.testing.assert_allclose(per_pixel, np.asarray(engine.tau_c_bounds().tau) * 0.1, rtol=1e-12)


@pytest.mark.parametrize(("shape", "configured", "block"),
                         [((2048, 2048), None, 8), ((512, 512), None, 2), ((256, 256), None, 1),
                          ((4096, 2168), None, 12), ((2048, 2048), 1, 1), ((64, 64), 16, 16)])
def test_the_map_block(shape: tuple[int, int], configured: int | None, block: int) -> None:
    assert map_block(shape, configured) == block
