"""The descriptor registry (edgedsm.estimators.registry): a map added in one place (one record,
registered by a fixture) is validated by the config, formed by the engine in the modes it allows
and refused in the others, reduced over regions, and judged above its noise floor or plainly; the
built-in records agree with what the code does with them."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import replace

import numpy as np
import pytest
from pydantic import ValidationError

from edgedsm.config.estimator import EstimatorSection
from edgedsm.errors import EstimatorError
from edgedsm.estimators import noise, noise_floor, registry
from edgedsm.estimators.batch import s1
from edgedsm.estimators.descriptors import DESCRIPTORS, compute
from edgedsm.estimators.engine_checks import estimator_names
from edgedsm.estimators.noise_floor import Floor
from edgedsm.estimators.noise_summary import region_floor, region_noise
from edgedsm.estimators.region_box import RegionBox
from edgedsm.estimators.region_stats import RegionPlan, region_moments
from edgedsm.estimators.registry import MODES, KernelSpec, Record
from edgedsm.estimators.snapshot import maps_from
from edgedsm.estimators.streaming import SlidingWindow
from edgedsm.estimators.value_set import flags_of

HERE = "tests.unit.estimators.test_registry"


def double_s1(s1_values: np.ndarray) -> np.ndarray:
    """The toy's formula from the fused pass's S1 values: 2·S1 (grey levels)."""
    return 2.0 * s1_values


def double_s1_batch(frames: np.ndarray, lag: int) -> np.ndarray:
    """The toy's batch reference: 2·S1 (Eq. 1) of the stack."""
    return 2.0 * s1(frames, lag)


def double_s1_floor(model: noise.NoiseModel, means: np.ndarray, n: int, lag: int, top: float = np.inf) -> Floor:
    """The toy's noise floor: twice S1's (value and spread scale with the map)."""
    floor = noise_floor.s1_floor(model, means, n, lag, top=top)
    return Floor(2.0 * floor.value, 2.0 * floor.spread)


#: A toy map kept to the window modes, with a noise floor.
TOY = Record("toy2s1", "grey levels", "2·S1", "2 mean |I_k - I_{k+m}|", "derived", frozenset({"abs"}), ("s1",),
             frozenset({"sliding", "tumbling"}), mode_reason="a test of the refusal in the {mode} mode",
             uses_lag=True, activity=True, derive=f"{HERE}:double_s1", floor=f"{HERE}:double_s1_floor",
             floor_args=("lag",), batch=f"{HERE}:double_s1_batch", batch_args=("lag",))


@pytest.fixture
def toy() -> Iterator[Record]:
    with registry.registered(TOY) as record:
        yield record
    assert TOY.name not in registry.REGISTRY


@pytest.fixture
def plain_toy() -> Iterator[Record]:
    """The toy without a noise floor, streamed in every mode."""
    with registry.registered(replace(TOY, floor=None, floor_args=(), modes=frozenset(MODES))) as record:
        yield record


def _frames(count: int = 40, shape: tuple[int, int] = (12, 16), seed: int = 3) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (count, *shape)).astype(np.uint8)


def test_the_config_takes_a_registered_map_and_its_modes(toy: Record) -> None:
    section = EstimatorSection(activity=toy.name, window=20, lag=2)
    assert section.maps == (*registry.paper_maps(), toy.name)
    assert EstimatorSection(activity=toy.name, mode="tumbling", window=20, lag=2).engine_q == section.q
    with pytest.raises(ValidationError, match=r"activity: toy2s1 needs mode 'sliding' or 'tumbling', not "
                                              r"'exponential' \(a test of the refusal in the exponential mode\)"):
        EstimatorSection(activity=toy.name, mode="exponential", window=20, lag=2)


def test_an_unregistered_map_is_refused_by_the_config() -> None:
    with pytest.raises(ValidationError, match="Input should be 's1', 's2', 's3', 'tau_c'"):
        EstimatorSection(activity=TOY.name)
    assert TOY.name not in registry.activities() and TOY.name not in estimator_names()


@pytest.mark.parametrize("kernel", ["numba", "numpy"])
@pytest.mark.parametrize("mode", MODES)
def test_the_engine_forms_it_in_its_modes_and_refuses_the_others(toy: Record, mode: str, kernel: str) -> None:
    frames = _frames()
    window, lag = 20, 3
    if mode not in toy.modes:
        with pytest.raises(EstimatorError, match=f"estimator 'toy2s1': toy2s1 needs mode .* not '{mode}'"):
            SlidingWindow(frames.shape[1:], window, lag, estimators=("s2", toy.name), mode=mode, kernel=kernel)
        return
    engine = SlidingWindow(frames.shape[1:], window, lag, estimators=("s2", toy.name), mode=mode, kernel=kernel)
    for frame in frames:
        engine.push(frame)
    maps = engine.maps()
    assert set(maps) == {"s2", toy.name}
    # sliding: the last N frames; tumbling: the last completed block, here the same 20 frames
    np.testing.assert_array_equal(maps[toy.name], double_s1_batch(frames[-window:], lag))
    np.testing.assert_array_equal(maps_from(engine.snapshot())[toy.name], maps[toy.name])
    # reduced over regions from the same sums: the map's mean and spread over the mask
    mask = np.zeros(frames.shape[1:], bool)
    mask[2:9, 3:14] = True
    plan = RegionPlan.of(RegionBox.of(mask), frames.shape[1:])
    moments = region_moments(engine.snapshot(live=True), {"patch": plan}, ["s2", toy.name])["patch"]
    assert moments[toy.name].pixels == mask.sum()
    assert moments[toy.name].mean == pytest.approx(float(maps[toy.name][mask].mean()), rel=1e-12)
    assert moments[toy.name].std == pytest.approx(float(maps[toy.name][mask].std()), rel=1e-9)
    assert moments["s2"].mean == pytest.approx(float(maps["s2"][mask].mean()), rel=1e-12)


def test_its_noise_floor_is_its_records(toy: Record) -> None:
    frames = _frames(count=24)
    model = noise.from_datasheet(0.5, 2.0)
    estimate = double_s1_batch(frames, 2)
    summary = region_noise(frames, estimate, toy.name, 2, model=model)
    plain = region_noise(frames, s1(frames, 2), "s1", 2, model=model)
    assert summary.noise_floor == pytest.approx(2.0 * plain.noise_floor, rel=1e-12)
    assert summary.estimate == pytest.approx(2.0 * plain.estimate, rel=1e-12)
    assert summary.above_noise == pytest.approx(2.0 * plain.above_noise, rel=1e-12)
    assert DESCRIPTORS[toy.name].noise_floor and toy.name in registry.with_floor()
    np.testing.assert_array_equal(compute(toy.name, frames, lag=2), estimate)


def test_without_a_floor_it_is_judged_plainly(plain_toy: Record) -> None:
    frames = _frames(count=24)
    model = noise.from_datasheet(0.5, 2.0)
    assert plain_toy.name not in registry.with_floor() and not DESCRIPTORS[plain_toy.name].noise_floor
    with pytest.raises(EstimatorError, match="estimator must be one of"):
        region_floor(frames, plain_toy.name, 2, model)
    with pytest.raises(EstimatorError, match="estimator must be one of"):
        region_noise(frames, double_s1_batch(frames, 2), plain_toy.name, 2, model=model)
    # every mode now: the exponential engine forms it too
    engine = SlidingWindow(frames.shape[1:], 10, 2, estimators=(plain_toy.name,), mode="exponential",
                           kernel="numpy")
    for frame in frames:
        engine.push(frame)
    single = SlidingWindow(frames.shape[1:], 10, 2, estimators=("s1",), mode="exponential", kernel="numpy")
    for frame in frames:
        single.push(frame)
    np.testing.assert_array_equal(engine.maps()[plain_toy.name], 2.0 * single.maps()["s1"])


def test_a_name_is_registered_once() -> None:
    with pytest.raises(ValueError, match="registered already"):
        registry.register(registry.get("s1"))
    with pytest.raises(KeyError, match="unknown map 'nope'"):
        registry.get("nope")


def test_a_record_states_what_it_needs() -> None:
    with pytest.raises(ValueError, match="say why"):
        replace(TOY, mode_reason="")
    with pytest.raises(ValueError, match="derive function"):
        replace(TOY, derive=None)
    with pytest.raises(ValueError, match="no modes"):
        replace(TOY, source="batch")
    with pytest.raises(ValueError, match="unknown sums"):
        replace(TOY, sums=frozenset({"frames"}))


def test_the_kernel_spec_is_the_old_flags() -> None:
    # the flags the engine used before the registry: S3 needs S1's sum, Fujii is formed from S2
    for names, flags in ((("s3",), (True, False, True, False, False, False)),
                         (("fujii",), (False, True, False, False, True, False)),
                         (("contrast", "im"), (False, False, False, True, False, True)),
                         (("gd", "tau_c", "band_ratio"), (False,) * 6),
                         (("s1", "s2", "s3"), (True, True, True, False, False, False))):
        assert KernelSpec.of(names).flags == flags == flags_of(names), names
    assert KernelSpec.of(["contrast"]).sigma and not KernelSpec.of(["fujii"]).sigma


def test_the_records_match_the_code() -> None:
    frames = _frames(count=16)
    for record in registry.REGISTRY.values():
        if record.batch is not None:  # the batch reference answers to its arguments
            out = compute(record.name, frames, lag=2, q=1.0, threshold=10.0)
            assert out.shape == frames.shape[1:] and np.isfinite(out).all(), record.name
        if record.value is not None:
            assert callable(registry.load(record.value)) and callable(registry.load(record.value_numpy)), record.name
        if record.floor is not None:
            assert callable(registry.load(record.floor)), record.name
        for mode in MODES:  # the engine refuses exactly the modes the record refuses
            problem = record.mode_problem(mode)
            if record.region_level:  # its own state beside the engine (kinetics): every mode, no engine map
                assert problem is None and record.name not in estimator_names()
                continue
            if not record.streams:
                assert problem is not None and record.name not in estimator_names()
                continue
            try:
                SlidingWindow((4, 4), 8, 1, q=0.0, estimators=(record.name,), mode=mode, kernel="numpy")
            except EstimatorError as exc:
                assert problem is not None and problem in str(exc), (record.name, mode)
            else:
                assert problem is None, (record.name, mode)
