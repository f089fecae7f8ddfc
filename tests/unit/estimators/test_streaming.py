"""Streaming engine (issue 3): exactness against the batch reference and exact rationals,
stated error bounds, degenerate cases, frame validation, modes and kernel identity.

The helpers at the top are shared with the other ``test_streaming_*.py`` files.
"""

from __future__ import annotations

import importlib.util
import math
import sys
from decimal import Decimal, localcontext
from fractions import Fraction

import numpy as np
import pytest

from edgedsm.errors import EstimatorError, FrameError
from edgedsm.estimators import SlidingWindow, all_maps, s3
from edgedsm.estimators.kernels_numpy import sigma_from_sums
from edgedsm.estimators.streaming import (
    PARALLEL_MIN_PIXELS,
    ratio_kind,
    ratio_lut,
    ratio_scale_bits,
    s2_error_bound,
)

U = 2.0**-53  # unit roundoff of float64
KERNELS = ["numpy"] + (["numba"] if importlib.util.find_spec("numba") else [])
MODES = ["sliding", "tumbling", "exponential"]


# --------------------------------------------------------------------------- shared helpers
def feed(engine: SlidingWindow, frames: np.ndarray) -> SlidingWindow:
    for frame in frames:
        engine.push(np.ascontiguousarray(frame))
    return engine


def reference_window(engine: SlidingWindow, frames: np.ndarray) -> np.ndarray:
    """The frames the engine's maps describe (sliding: last N; tumbling: last full block)."""
    n = engine.window
    if engine.mode == "tumbling":
        end = engine.blocks_completed * n
        return frames[end - n:end]
    return frames[-n:]


def assert_matches_batch(engine: SlidingWindow, frames: np.ndarray) -> None:
    """S1 and S3 bit-identical to the batch reference, S2 within the stated bound plus the
    batch's own float64 summation error ((N-m+2)·u, its terms being <= 1)."""
    ref = all_maps(reference_window(engine, frames), engine.lag, engine.q)
    got = engine.maps()
    if "s1" in got:
        np.testing.assert_array_equal(got["s1"], ref["s1"])
    if "s3" in got:
        np.testing.assert_array_equal(got["s3"], ref["s3"])
    if "s2" in got:
        tolerance = engine.s2_bound + (engine.pairs + 2) * U
        assert np.max(np.abs(got["s2"] - ref["s2"])) <= tolerance


def exact_s2(window: np.ndarray, lag: int, q: float) -> np.ndarray:
    """S2 of Eq. 2 in rational arithmetic (no rounding at all), as Fractions per pixel."""
    flat = window.reshape(window.shape[0], -1)
    q_exact = Fraction(q)
    pairs = window.shape[0] - lag
    out = []
    for p in range(flat.shape[1]):
        total = Fraction(0)
        for i in range(pairs):
            a, b = int(flat[i, p]), int(flat[i + lag, p])
            if a + b + q_exact:
                total += Fraction(abs(a - b)) / (a + b + q_exact)
        out.append(total / pairs)
    return np.array(out, dtype=object).reshape(window.shape[1:])


def assert_s2_within_bound(got: np.ndarray, exact: np.ndarray, bound: float) -> None:
    for value, true in zip(got.ravel(), exact.ravel(), strict=True):
        assert abs(Fraction(float(value)) - true) <= Fraction(bound), (value, float(true))


def exponential_reference(frames: np.ndarray, window: int, lag: int, q: float
                          ) -> dict[str, np.ndarray]:
    """Exponential-mode definition (weights λ^k, λ = 1 - 1/N exactly) in 40-digit decimals.

    ``frames`` are all frames seen, or a trailing stretch long enough that λ^length is
    negligible. Returns float64 maps s1, s2 and var (σ²).
    """
    flat = frames.reshape(frames.shape[0], -1)
    count = flat.shape[0]
    out = {key: np.zeros(flat.shape[1]) for key in ("s1", "s2", "var")}
    with localcontext() as ctx:
        ctx.prec = 40
        lam = Decimal(window - 1) / Decimal(window)
        weights = [Decimal(1)]
        for _ in range(count - 1):
            weights.append(weights[-1] * lam)
        w_sum = sum(weights)
        q_dec = Decimal(q)  # the exact binary value of the float
        for p in range(flat.shape[1]):
            values = [Decimal(int(v)) for v in flat[::-1, p]]  # newest first
            mean = sum(w * v for w, v in zip(weights, values, strict=True)) / w_sum
            var = sum(w * (v - mean) ** 2 for w, v in zip(weights, values, strict=True)) / w_sum
            pair_w = s1 = s2 = Decimal(0)
            for k in range(count - lag):
                a, b = values[k], values[k + lag]
                s1 += weights[k] * abs(a - b)
                if a + b + q_dec:
                    s2 += weights[k] * abs(a - b) / (a + b + q_dec)
                pair_w += weights[k]
            out["s1"][p] = float(s1 / pair_w)
            out["s2"][p] = float(s2 / pair_w)
            out["var"][p] = float(var)
    return {key: value.reshape(frames.shape[1:]) for key, value in out.items()}


def assert_matches_exponential(engine: SlidingWindow, frames: np.ndarray) -> None:
    """Exponential maps within the bounds stated in the streaming module's docstring."""
    ref = exponential_reference(frames, engine.window, engine.lag, engine.q)
    top = float(2**engine.bits - 1)
    n = engine.window
    got = engine.maps()
    assert np.max(np.abs(got["s1"] - ref["s1"])) <= 8 * n * U * top
    assert np.max(np.abs(got["s2"] - ref["s2"])) <= 8 * n * U
    assert np.max(np.abs(engine.sigma() ** 2 - ref["var"])) <= 16 * n * U * top * top


def assert_snapshots_equal(first: dict, second: dict) -> None:
    assert first.keys() == second.keys()
    for key, value in first.items():
        if isinstance(value, np.ndarray):
            assert value.dtype == second[key].dtype, key
            np.testing.assert_array_equal(value, second[key], err_msg=key)
        else:
            assert value == second[key], key


def random_frames(seed: int, count: int, shape: tuple[int, int], bits: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    dtype = np.uint8 if bits <= 8 else np.uint16
    top = 2**bits - 1
    frames = rng.integers(0, top + 1, size=(count, *shape)).astype(dtype)
    # adversarial columns: zeros (0/0 in S2 when q = 0), saturated, 0/max alternation
    frames[:, 0, 0] = 0
    frames[:, 0, -1] = top
    frames[:, -1, 0] = np.where(np.arange(count) % 2, top, 0)
    return frames


# --------------------------------------------------------------------------- exactness
@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("bits", [8, 12, 16])
@pytest.mark.parametrize(("window", "lag"), [(2, 1), (7, 1), (7, 6), (12, 5), (20, 10)])
def test_sliding_equals_batch_after_every_frame(kernel, bits, window, lag):
    frames = random_frames(window * 31 + lag, 3 * window + 5, (3, 4), bits)
    engine = SlidingWindow((3, 4), window, lag, q=0.0, kernel=kernel, bits=bits)
    for i, frame in enumerate(frames):
        engine.push(frame)
        assert engine.frames_seen == i + 1
        assert engine.ready == (i + 1 >= window)
        if engine.ready:
            assert_matches_batch(engine, frames[:i + 1])


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("q", [0.0, 1.0, 2.75, 0.1])
@pytest.mark.parametrize("bits", [8, 10, 16])
def test_s2_against_exact_rationals(kernel, q, bits):
    window, lag = 9, 2
    frames = random_frames(int(q * 100) + bits, 23, (2, 5), bits)
    engine = feed(SlidingWindow((2, 5), window, lag, q=q, kernel=kernel), frames)
    assert engine.s2_bound == s2_error_bound(window - lag, bits, q)
    # uint16 frames and no ``bits``: the engine takes them as 16-bit data
    assert engine.ratio_kind == ("float" if bits > 8 else "exact" if q.is_integer() else "lut")
    assert engine.s2_bound < 1e-15
    assert_s2_within_bound(engine.maps()["s2"], exact_s2(frames[-window:], lag, q), engine.s2_bound)


@pytest.mark.parametrize("q", [0.0, 0.1, 3.0])
def test_ratio_table_is_exactly_rounded(q):
    """Every 8-bit fixed-point term is within half a unit (2^-(K+1)) of the rational term."""
    k = ratio_scale_bits(190)
    assert k == 55
    table = ratio_lut(q, k)
    q_num, q_den = Fraction(q).numerator, Fraction(q).denominator
    for a in range(256):
        for b in range(256):
            # term = |a-b|·q_den / ((a+b)·q_den + q_num); check |T·D - num·2^K| <= D/2
            numerator, denominator = abs(a - b) * q_den, (a + b) * q_den + q_num
            value = int(table[(a << 8) | b])
            if denominator == 0:
                assert value == 0
            else:
                assert 2 * abs(value * denominator - (numerator << k)) <= denominator, (a, b)
    assert not table.flags.writeable


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("q", [0.0, 1.0, 7.0, 1000.0])
def test_exact_terms_equal_the_rational_table(kernel, q):
    """The vectorised "exact" S2 terms (float estimate + one integer correction) are the
    exactly rounded values, for every pair of 8-bit values."""
    k = ratio_scale_bits(190, "exact")
    assert k == 51
    a, b = np.meshgrid(np.arange(256), np.arange(256), indexing="ij")
    first, second = a.ravel().astype(np.uint8), b.ravel().astype(np.uint8)
    module = importlib.import_module(f"edgedsm.estimators.kernels_{kernel}")
    abs_sum, ratio = np.zeros(65536, np.int64), np.zeros(65536, np.int64)
    module.pairs_kernel(True, True, "exact", True)(first, second, abs_sum, ratio, np.zeros(0, np.int64),
                                                   np.zeros(0, np.int64), float(2**k), q)
    np.testing.assert_array_equal(ratio, ratio_lut(q, k))
    np.testing.assert_array_equal(abs_sum, np.abs(a - b).ravel())


def test_ratio_kinds():
    assert ratio_kind(8, 0.0) == "exact" and ratio_kind(5, 3.0) == "exact"
    assert ratio_kind(8, 0.5) == "lut" and ratio_kind(8, 2.0**41) == "lut"
    assert ratio_kind(10, 0.0) == "float" and ratio_kind(16, 0.5) == "float"
    assert ratio_scale_bits(190, "lut") == 55 and ratio_scale_bits(1, "lut") == 62
    assert ratio_scale_bits(1, "float") == ratio_scale_bits(190, "float") == 51  # y < 2^52


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("bits", [8, 16])
def test_tumbling_equals_batch_on_the_last_completed_block(kernel, bits):
    window, lag = 10, 3
    frames = random_frames(5, 47, (3, 3), bits)
    engine = SlidingWindow((3, 3), window, lag, q=0.5, mode="tumbling", kernel=kernel)
    for i, frame in enumerate(frames):
        engine.push(frame)
        assert engine.blocks_completed == (i + 1) // window
        if engine.ready:
            assert_matches_batch(engine, frames[:i + 1])
    # maps stay those of block 3 (frames 30..39) until block 4 completes
    assert engine.blocks_completed == 4
    np.testing.assert_array_equal(engine.maps()["s1"], all_maps(frames[30:40], lag)["s1"])


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize(("bits", "q"), [(8, 0.0), (12, 1.5)])
def test_exponential_matches_its_definition(kernel, bits, q):
    window, lag = 6, 2
    frames = random_frames(11, 40, (2, 3), bits)
    engine = SlidingWindow((2, 3), window, lag, q=q, mode="exponential", kernel=kernel)
    for i, frame in enumerate(frames):
        engine.push(frame)
        if engine.ready and i % 7 == 0:
            assert_matches_exponential(engine, frames[:i + 1])
    assert_matches_exponential(engine, frames)


def test_exponential_forgets_old_frames():
    """After many time constants a changed stream is all the maps see."""
    frames = random_frames(2, 300, (2, 2), 8)
    frames[100:] = 40  # 200 frames = 40 time constants: λ^200 < 1e-19
    engine = feed(SlidingWindow((2, 2), 5, 1, mode="exponential"), frames)
    maps = engine.maps()
    assert np.all(maps["s1"] < 1e-6) and np.all(maps["s2"] < 1e-6)
    assert np.all(engine.sigma() < 1e-3)


# --------------------------------------------------------------------------- degenerate cases
@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("mode", MODES)
def test_sigma_zero_and_zero_intensity_give_defined_values(kernel, mode):
    window, lag = 8, 3
    frames = np.zeros((3 * window, 2, 2), np.uint8)
    frames[:, 0, 1] = 255  # saturated
    frames[:, 1, 0] = 77  # constant
    frames[:, 1, 1] = np.where(np.arange(3 * window) % 2, 255, 0)  # 0/max alternation
    engine = feed(SlidingWindow((2, 2), window, lag, q=0.0, mode=mode, kernel=kernel), frames)
    maps = engine.maps()
    for values in maps.values():
        assert np.isfinite(values).all()
    # constant, saturated and all-zero pixels: no activity at all, S3 = 0 where σ = 0
    for name in ("s1", "s2", "s3"):
        assert maps[name][0, 0] == 0.0 and maps[name][0, 1] == 0.0 and maps[name][1, 0] == 0.0
    # odd lag on 0/max alternation: every pair is (0, 255): S1 = 255 and S2 = 1 exactly
    assert maps["s1"][1, 1] == 255.0
    assert maps["s2"][1, 1] == 1.0
    if mode != "exponential":
        assert maps["s3"][1, 1] == 2.0  # σ = 127.5 over an even window


@pytest.mark.parametrize("kernel", KERNELS)
def test_full_scale_16_bit_sums_do_not_overflow(kernel):
    """N·ΣI² of a saturated 16-bit pixel passes 2^63 here; σ must still be exact."""
    window, lag = 50_000, 1
    count = window + 17
    frames = np.empty((count, 1, 3), np.uint16)
    frames[:, 0, 0] = 65535
    frames[:, 0, 1] = np.where(np.arange(count) % 2, 65535, 0)
    frames[:, 0, 2] = np.where(np.arange(count) % 3, 65535, 65534)
    assert window * (window * 65535**2) > 2**63  # the naive N·ΣI² would overflow
    engine = feed(SlidingWindow((1, 3), window, lag, kernel=kernel), frames)
    sigma = engine.sigma()[0]
    assert sigma[0] == 0.0
    assert sigma[1] == 32767.5
    tail = frames[-window:, 0, 2].astype(object)
    spread = window * sum(v * v for v in tail) - sum(tail) ** 2  # exact Python integers
    assert sigma[2] == math.sqrt(spread) / window
    maps = engine.maps()
    assert maps["s1"][0, 1] == 65535.0 and maps["s3"][0, 0] == 0.0
    np.testing.assert_array_equal(maps["s3"], s3(frames[-window:], lag))


@pytest.mark.parametrize("kernel", KERNELS)
def test_sigma_beyond_int64_uses_a_cancellation_free_float(kernel):
    n = 2**21  # N·Σ(I-k)² ~ 2^72 for the first pixel: the float branch
    total = np.array([n // 2 * 65535, n * 65535, n * 30000 + 12345], np.int64)
    total_sq = np.array([n // 2 * 65535**2, n * 65535**2, n * 30000**2 + 12345 * 60001],
                        np.int64)
    module = importlib.import_module(f"edgedsm.estimators.kernels_{kernel}")
    s1, sigma, s3 = np.empty(3), np.empty(3), np.empty(3)
    abs_sum = np.array([7, 0, 9], np.int64)
    module.maps_kernel(True, False, True, False)(abs_sum, np.zeros(0, np.int64), total, total_sq,
                                                 np.zeros(0, np.int64), 5, 1.0, n, s1, np.empty(0), s3,
                                                 sigma, np.empty(0), np.empty(0), np.empty(0), 1.0)
    for value, s, s2 in zip(sigma, total.tolist(), total_sq.tolist(), strict=True):
        exact = math.sqrt(Fraction(n * s2 - s * s, n * n))
        assert abs(value - exact) <= 2**-50 * exact
    assert sigma[1] == 0.0 and s3[1] == 0.0
    assert sigma[0] == 32767.5
    np.testing.assert_array_equal(sigma, sigma_from_sums(total, total_sq, n))
    np.testing.assert_array_equal(s3[[0, 2]], (abs_sum / 5)[[0, 2]] / sigma[[0, 2]])


# --------------------------------------------------------------------------- kernels
@pytest.mark.skipif("numba" not in KERNELS, reason="numba not installed")
@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize(("bits", "q"), [(8, 0.0), (8, 0.3), (12, 0.0), (16, 2.5)])
def test_numba_and_numpy_kernels_are_bit_identical(mode, bits, q):
    # 80 000 pixels: several numpy chunks, and the parallel numba kernels
    # (the hypothesis tests cover small frames and the single-thread ones)
    assert PARALLEL_MIN_PIXELS <= 200 * 400
    frames = random_frames(bits, 45, (200, 400), bits)
    engines = [SlidingWindow((200, 400), 20, 7, q=q, mode=mode, kernel=kernel)
               for kernel in ("numba", "numpy")]
    for frame in frames:
        for engine in engines:
            engine.push(frame)
    assert_snapshots_equal(engines[0]._snapshot(), engines[1]._snapshot())
    first, second = engines[0].maps(), engines[1].maps()
    for name in first:
        np.testing.assert_array_equal(first[name], second[name])


@pytest.mark.skipif("numba" not in KERNELS, reason="numba not installed")
def test_thread_count_does_not_change_results():
    frames = random_frames(3, 30, (256, 256), 8)
    one = feed(SlidingWindow((256, 256), 12, 4, kernel="numba", threads=1), frames)
    default = feed(SlidingWindow((256, 256), 12, 4, kernel="numba"), frames)
    assert_snapshots_equal(one._snapshot(), default._snapshot())
    with pytest.raises(EstimatorError, match="threads"):
        SlidingWindow((4, 4), 12, 4, kernel="numba", threads=10_000)


def test_numpy_fallback_when_numba_is_missing(monkeypatch):
    monkeypatch.setitem(sys.modules, "edgedsm.estimators.kernels_numba", None)
    assert SlidingWindow((2, 2), 4, 1, kernel="auto").kernel == "numpy"
    with pytest.raises(EstimatorError, match="needs numba"):
        SlidingWindow((2, 2), 4, 1, kernel="numba")


# --------------------------------------------------------------------------- subsets, resync, reset
@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("mode", MODES)
@pytest.mark.parametrize("estimators", [("s1",), ("s2",), ("s3",), ("s2", "s1")])
def test_estimator_subsets_equal_the_full_engine(kernel, mode, estimators):
    frames = random_frames(8, 30, (3, 4), 8)
    full = feed(SlidingWindow((3, 4), 9, 2, q=1.0, mode=mode, kernel=kernel), frames).maps()
    part = feed(SlidingWindow((3, 4), 9, 2, q=1.0, mode=mode, kernel=kernel,
                              estimators=estimators), frames)
    maps = part.maps()
    assert tuple(maps) == tuple(name for name in ("s1", "s2", "s3") if name in estimators)
    for name, values in maps.items():
        np.testing.assert_array_equal(values, full[name])
    assert part.bytes_per_pixel < SlidingWindow((3, 4), 9, 2, mode=mode, bits=8).bytes_per_pixel


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("bits", [8, 14])
def test_resync_reproduces_the_running_sums_bit_for_bit(kernel, bits):
    frames = random_frames(21, 95, (4, 4), bits)
    engine = feed(SlidingWindow((4, 4), 13, 4, q=0.25, kernel=kernel), frames)
    before = engine._snapshot()
    engine.resync()
    assert_snapshots_equal(before, engine._snapshot())
    # it repairs damage from outside (a flipped bit in a sum)
    engine._arrays["ratio"][3] ^= 1 << 40
    engine._arrays["total_sq"][5] += 1
    engine.resync()
    assert_snapshots_equal(before, engine._snapshot())


@pytest.mark.parametrize("kernel", KERNELS)
def test_resync_every_keeps_results_and_refuses_other_modes(kernel):
    frames = random_frames(4, 40, (3, 3), 8)
    plain = feed(SlidingWindow((3, 3), 8, 3, kernel=kernel), frames)
    synced = feed(SlidingWindow((3, 3), 8, 3, kernel=kernel, resync_every=5), frames)
    assert_snapshots_equal(plain._snapshot(), synced._snapshot())
    with pytest.raises(EstimatorError, match="sliding"):
        SlidingWindow((3, 3), 8, 3, mode="tumbling", resync_every=5)
    with pytest.raises(EstimatorError, match="sliding"):
        SlidingWindow((3, 3), 8, 3, mode="exponential").resync()


@pytest.mark.parametrize("mode", MODES)
def test_reset_starts_afresh(mode):
    frames = random_frames(6, 30, (2, 3), 8)
    engine = feed(SlidingWindow((2, 3), 7, 2, mode=mode), frames)
    engine.reset()
    assert engine.frames_seen == 0 and not engine.ready and engine.bits is None
    with pytest.raises(EstimatorError, match="not full"):
        engine.maps()
    # the inferred bit depth is forgotten too: 16-bit frames are welcome now
    wide = random_frames(7, 20, (2, 3), 16)
    feed(engine, wide)
    fresh = feed(SlidingWindow((2, 3), 7, 2, mode=mode), wide)
    assert_snapshots_equal(engine._snapshot(), fresh._snapshot())


# --------------------------------------------------------------------------- validation
def _bad_frames() -> list[tuple[object, str]]:
    good = np.zeros((4, 6), np.uint16)
    return [
        ([[0] * 6] * 4, "numpy array"),
        (np.zeros((4, 5), np.uint16), "shape"),
        (np.zeros((6, 4), np.uint16), "shape"),
        (np.zeros((1, 4, 6), np.uint16), "shape"),
        (np.zeros((4, 6), np.uint8), "dtype"),
        (np.zeros((4, 6), np.float64), "dtype"),
        (np.zeros((4, 6), np.int16), "dtype"),
        (np.zeros((4, 6), ">u2"), "dtype"),
        (np.asfortranarray(np.zeros((4, 6), np.uint16)), "contiguous"),
        (np.zeros((4, 12), np.uint16)[:, ::2], "contiguous"),
        (np.full((4, 6), 1024, np.uint16), "above the 10-bit"),
        (np.where(np.eye(4, 6, dtype=bool), 4095, 0).astype(np.uint16), "above the 10-bit"),
        (good.T, "shape"),
    ]


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("mode", MODES)
def test_refused_frames_leave_the_engine_untouched(kernel, mode):
    frames = random_frames(9, 25, (4, 6), 10)
    engine = SlidingWindow((4, 6), 7, 3, bits=10, mode=mode, kernel=kernel)
    twin = SlidingWindow((4, 6), 7, 3, bits=10, mode=mode, kernel=kernel)
    for i, frame in enumerate(frames):
        if i % 5 == 2:
            before = engine._snapshot()
            for bad, message in _bad_frames():
                with pytest.raises(FrameError, match=message):
                    engine.push(bad)  # type: ignore[arg-type]
                assert_snapshots_equal(before, engine._snapshot())
        engine.push(frame)
        twin.push(frame)
    assert_snapshots_equal(engine._snapshot(), twin._snapshot())


def test_bit_depth_is_inferred_from_the_first_frame():
    engine = SlidingWindow((2, 2), 4, 1)
    with pytest.raises(FrameError, match="uint8 or uint16"):
        engine.push(np.zeros((2, 2), np.int32))
    assert engine.bits is None and engine.frames_seen == 0
    engine.push(np.zeros((2, 2), np.uint16))
    assert engine.bits == 16
    with pytest.raises(FrameError, match="dtype uint8"):
        engine.push(np.zeros((2, 2), np.uint8))
    explicit = SlidingWindow((2, 2), 4, 1, bits=12)
    assert explicit.bits == 12
    explicit.push(np.full((2, 2), 4095, np.uint16))
    with pytest.raises(FrameError, match="4096 is above the 12-bit range"):
        explicit.push(np.full((2, 2), 4096, np.uint16))
    low = SlidingWindow((2, 2), 4, 1, bits=6)
    with pytest.raises(FrameError, match="above the 6-bit"):
        low.push(np.full((2, 2), 64, np.uint8))


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"window": 1}, "window"),
    ({"window": 2.0}, "window"),
    ({"lag": 0}, "lag"),
    ({"lag": 10}, "lag"),
    ({"lag": True}, "lag"),
    ({"q": -1.0}, "q must be"),
    ({"q": float("nan")}, "q must be"),
    ({"q": "1"}, "q must be"),
    ({"bits": 17}, "bits"),
    ({"bits": 0}, "bits"),
    ({"estimators": ()}, "estimators"),
    ({"estimators": ("s4",)}, "estimators"),
    ({"mode": "rolling"}, "mode"),
    ({"kernel": "cuda"}, "kernel"),
    ({"threads": 0}, "threads"),
    ({"resync_every": 0}, "resync_every"),
    ({"shape": (3,)}, "shape"),
    ({"shape": (0, 3)}, "height"),
    ({"shape": 5}, "shape"),
])
def test_bad_arguments_are_refused_with_a_clear_message(kwargs, message):
    arguments = {"shape": (3, 3), "window": 10, "lag": 2} | kwargs
    with pytest.raises(EstimatorError, match=message):
        SlidingWindow(**arguments)


def test_maps_before_the_window_is_full_are_refused():
    engine = SlidingWindow((2, 2), 5, 1, estimators="s1")
    assert engine.estimators == ("s1",)
    feed(engine, np.zeros((4, 2, 2), np.uint8))
    assert not engine.ready
    with pytest.raises(EstimatorError, match="4 of 5 frames"):
        engine.maps()
    engine.push(np.zeros((2, 2), np.uint8))
    assert engine.ready and set(engine.maps()) == {"s1"}
    with pytest.raises(EstimatorError, match="needs 's3'"):
        engine.sigma()


# --------------------------------------------------------------------------- memory
def test_memory_per_pixel_is_as_documented():
    """The module docstring's table: 8-bit, N = 200, m = 10, all three maps."""
    expected = {"sliding": 220, "tumbling": 51, "exponential": 42}
    for mode, value in expected.items():
        engine = SlidingWindow((16, 16), 200, 10, bits=8, mode=mode)
        assert engine.bytes_per_pixel == value
        assert sum(a.nbytes for a in engine._arrays.values()) == value * 256
    wide = SlidingWindow((16, 16), 200, 10, bits=16)
    assert wide.bytes_per_pixel == 2 * 200 + 4 + 8 + 4 + 8  # ΣI² needs int64 at 16 bits


def test_maps_can_leave_the_costly_tau_map_out():
    frames = np.random.default_rng(8).integers(0, 256, (12, 9, 7), dtype=np.uint8)
    engine = SlidingWindow((9, 7), 8, 2, bits=8, estimators=("s1", "s2", "s3", "tau_c"), max_lag=3)
    for frame in frames:
        engine.push(frame)
    everything = engine.maps()
    some = engine.maps(("s1", "s3"))
    assert list(some) == ["s1", "s3"]
    assert np.array_equal(some["s1"], everything["s1"]) and np.array_equal(some["s3"], everything["s3"])
    assert np.array_equal(engine.maps(("tau_c",))["tau_c"], everything["tau_c"])
    with pytest.raises(EstimatorError, match=r"\['s4'\] were not requested"):
        engine.maps(("s4",))


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("mode", ["sliding", "tumbling"])
def test_the_engine_reads_exact_terms_from_the_table_with_the_formulas_sums(kernel, mode):
    """8-bit data and an integer q: the kernels read each S2 term from the exactly rounded table
    (faster than a division and its correction), and the running sums are the formula's, bit for bit."""
    rng = np.random.default_rng(7)
    frames = np.minimum(rng.exponential(70.0, (130, 24, 20)), 255).astype(np.uint8)
    tabled, formula = (SlidingWindow((24, 20), 40, 3, q=1.0, bits=8, estimators=("s1", "s2"), kernel=kernel,
                                     mode=mode) for _ in range(2))
    assert tabled.ratio_kind == "exact" and tabled._moments.lut.size == 65536
    formula._moments.lut = np.zeros(0, np.int64)  # what the kernels did before: the formula per term
    for frame in frames:
        tabled.push(frame)
        formula.push(frame)
    np.testing.assert_array_equal(tabled._arrays["ratio"], formula._arrays["ratio"])
    np.testing.assert_array_equal(tabled.maps()["s2"], formula.maps()["s2"])


def test_the_engine_shows_its_constructors_signature():
    import inspect

    parameters = list(inspect.signature(SlidingWindow).parameters)
    assert parameters[:5] == ["shape", "window", "lag", "q", "bits"] and "mode" in parameters
    assert "args" not in parameters and "kwargs" not in parameters
