"""Region τc of tumbling windows pooled as the frames arrive (edgedsm.estimators.tau_regions)
equals the engine's region_tau_c (per-pixel lag products) to rounding: random and simulated
stacks, 8 and 16 bits, overlapping and odd-shaped regions, with and without numba."""

from __future__ import annotations

import numpy as np
import pytest

from edgedsm.errors import EstimatorError
from edgedsm.estimators import SlidingWindow, tau_regions
from edgedsm.estimators.correlation_time import MEASURED, NO_SIGNAL
from edgedsm.estimators.tau_regions import TumblingRegionTau
from edgedsm.sim import Simulator, scene_from_dict

H, W = 36, 44


def _regions() -> dict[str, np.ndarray]:
    y, x = np.mgrid[:H, :W]
    disc = np.hypot(y - 17, x - 20) < 12
    return {"all": np.ones((H, W), bool), "disc": disc,
            "ring_part": disc & (np.hypot(y - 17, x - 20) > 6) & (x > 15),  # inside "disc": overlapping
            "comb": (x % 3 == 0) & (y > 10),  # odd shape across the others
            "pixel": (y == 3) & (x == 40)}


def _random(count: int, bits: int, seed: int, shape: tuple[int, int] = (H, W)) -> np.ndarray:
    # complex Gaussian AR(1) field (τc = 4 frames in intensity) scaled to the bit depth
    rng = np.random.default_rng(seed)
    r = np.exp(-1 / 8)
    field = rng.standard_normal((2, *shape))
    frames = np.empty((count, *shape), np.uint8 if bits <= 8 else np.uint16)
    for t in range(count):
        field = r * field + np.sqrt(1 - r * r) * rng.standard_normal((2, *shape))
        frames[t] = np.clip((field**2).sum(axis=0) * (2**bits / 8), 0, 2**bits - 1)
    frames[:, 0, :5] = frames[0, 0, :5]  # constant pixels: σ = 0
    return frames


def _simulated(count: int, bits: int) -> np.ndarray:
    scene = {"scene": {"size": W, "frames": count, "seed": 4},
             "activity": {"tau_c": 6.0, "regions": [{"shape": "rect", "x": 0, "y": 0, "width": 20, "height": H,
                                                      "tau_c": 15.0}]},
             "detector": {"n_max": 1000, "bits": bits}}
    frames = np.stack(list(Simulator(scene_from_dict(scene)).frames()))
    return np.ascontiguousarray(frames[:, :H, :W])


@pytest.fixture(params=["compiled", "numpy"])
def path(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    if request.param == "numpy":
        monkeypatch.setattr(tau_regions, "numba", None)
    elif tau_regions.numba is None:
        pytest.skip("numba is not installed")
    return str(request.param)


def _both(frames: np.ndarray, bits: int, window: int, max_lag: int) -> list[tuple[str, object, object]]:
    regions = _regions()
    engine = SlidingWindow((H, W), window, 3, bits=bits, mode="tumbling", estimators=("s1", "tau_c"),
                           max_lag=max_lag)
    pooled = TumblingRegionTau((H, W), regions, window, max_lag, bits)
    pairs = []
    for frame in frames:
        engine.push(np.ascontiguousarray(frame))
        result = pooled.push(np.ascontiguousarray(frame))
        assert (result is None) == (engine.frames_seen % window != 0)
        if result is not None:
            pairs += [(name, engine.region_tau_c(mask), result[name]) for name, mask in regions.items()]
    return pairs


@pytest.mark.parametrize(("source", "bits", "window", "max_lag"),
                         [("random", 8, 50, 20), ("random", 16, 40, 12), ("random", 12, 30, 28),
                          ("simulated", 8, 60, 20), ("simulated", 16, 50, 10)])
def test_region_tau_equals_the_engines(path: str, source: str, bits: int, window: int, max_lag: int) -> None:
    frames = _random(3 * window + 7, bits, seed=bits) if source == "random" else _simulated(3 * window + 7, bits)
    pairs = _both(frames, bits, window, max_lag)
    assert len(pairs) == 3 * len(_regions())
    measured = 0
    for name, engine, pooled in pairs:
        assert pooled.status == engine.status, name
        assert pooled.tau == pytest.approx(engine.tau, rel=1e-12, abs=1e-12), name
        measured += engine.status == MEASURED
    assert measured >= len(pairs) - 3  # the one-pixel region may read otherwise


@pytest.mark.parametrize("layout", ["one region", "chunks whole, empty and mixed"])
def test_chunks_wholly_in_one_region_or_in_none(path: str, layout: str) -> None:
    # 96 x 128 = 3 chunks of 4096 pixels: rows 0-31, 32-63, 64-95
    shape = (96, 128)
    regions = {"all": np.ones(shape, bool)}
    if layout != "one region":
        regions = {"top": np.zeros(shape, bool), "corner": np.zeros(shape, bool)}
        regions["top"][:32] = True  # chunk 0 wholly in it, chunk 1 in no region
        regions["corner"][90:, :7] = True  # chunk 2 mixed
    assert tau_regions.CHUNK == 4096
    frames = _random(90, 8, seed=7, shape=shape)
    engine = SlidingWindow(shape, 40, 3, bits=8, mode="tumbling", estimators=("s1", "tau_c"), max_lag=12)
    pooled = TumblingRegionTau(shape, regions, 40, 12, 8)
    compared = 0
    for frame in frames:
        engine.push(frame)
        if result := pooled.push(frame):
            for name, mask in regions.items():
                expected = engine.region_tau_c(mask)
                assert result[name].status == expected.status == MEASURED
                assert result[name].tau == pytest.approx(expected.tau, rel=1e-12)
                compared += 1
    assert compared == 2 * len(regions)


def test_the_compiled_and_numpy_paths_agree_bit_for_bit(monkeypatch: pytest.MonkeyPatch) -> None:
    if tau_regions.numba is None:
        pytest.skip("numba is not installed")
    frames = _random(60, 10, seed=3)
    results = []
    for numba in (tau_regions.numba, None):
        monkeypatch.setattr(tau_regions, "numba", numba)
        pooled = TumblingRegionTau((H, W), _regions(), 30, 8, 10)
        results.append([pooled.push(frame) for frame in frames][-1])
    assert results[0] == results[1]


def test_constant_region_has_no_signal_and_the_window_restarts() -> None:
    frames = _random(40, 8, seed=1)
    regions = {"dead": np.zeros((H, W), bool), "all": np.ones((H, W), bool)}
    regions["dead"][0, :5] = True  # the stack's constant pixels
    pooled = TumblingRegionTau((H, W), regions, 20, 6, 8)
    first = [pooled.push(frame) for frame in frames[:20]][-1]
    assert first["dead"] == (0.0, NO_SIGNAL) and first["all"].status == MEASURED
    second = [pooled.push(frame) for frame in frames[20:]][-1]
    alone = TumblingRegionTau((H, W), regions, 20, 6, 8)
    assert [alone.push(frame) for frame in frames[20:]][-1] == second  # nothing of the first window left


def test_memory_per_pixel_is_the_ring_and_head_sums() -> None:
    pooled = TumblingRegionTau((H, W), _regions(), 200, 20, 8)
    # 20 frames + 9 head sums (uint16) + T (uint16: 200 x 255 fits) + the atom label (uint8)
    assert pooled.bytes_per_pixel == 20 + 9 * 2 + 2 + 1
    engine = SlidingWindow((H, W), 200, 5, bits=8, mode="tumbling", estimators=("s1", "s2", "s3", "tau_c"),
                           max_lag=20)
    plain = SlidingWindow((H, W), 200, 5, bits=8, mode="tumbling", estimators=("s1", "s2", "s3"))
    assert engine.bytes_per_pixel - plain.bytes_per_pixel > 5 * pooled.bytes_per_pixel


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"regions": {}}, "1 to 62 regions"),
    ({"bits": 17}, "bits must be 1..16"),
    ({"max_lag": 19}, "does not fit a window"),
    ({"regions": {"none": np.zeros((H, W), bool)}}, "selects no pixel"),
    ({"regions": {"small": np.ones((3, 3), bool)}}, "does not match"),
    ({"window": 40_000, "bits": 16}, "too long for exact int64 sums"),
])
def test_bad_arguments_are_refused(kwargs: dict, message: str) -> None:
    arguments = {"shape": (H, W), "regions": {"all": np.ones((H, W), bool)}, "window": 20, "max_lag": 6, "bits": 8}
    arguments.update(kwargs)
    with pytest.raises(EstimatorError, match=message):
        TumblingRegionTau(**arguments)


def test_a_frame_of_another_type_is_refused() -> None:
    pooled = TumblingRegionTau((H, W), {"all": np.ones((H, W), bool)}, 20, 6, 8)
    with pytest.raises(EstimatorError, match="uint8"):
        pooled.push(np.zeros((H, W), np.uint16))
