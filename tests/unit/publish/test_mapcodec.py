"""Maps as 16-bit PNG + meta: a subscriber rebuilds the float map within half a quantization step."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from edgedsm.publish import MapCodecError, decode_map, downsample_map, encode_map


def _round_trip(values: np.ndarray, **kwargs) -> tuple[np.ndarray, dict]:
    png, meta = encode_map(values, estimator="s1", **kwargs)
    meta = json.loads(json.dumps(meta))  # as a subscriber receives it
    return decode_map(png, meta), meta


def _tolerance(values: np.ndarray, meta: dict) -> float:
    # Half a step, plus float64 rounding of offset + q * scale; a subnormal scale is rounded to a
    # multiple of the smallest subnormal, an error that q (up to 65535) multiplies.
    tiny = 65535 * np.finfo(np.float64).smallest_subnormal
    return meta["scale"] / 2 + 4 * np.finfo(np.float64).eps * float(np.max(np.abs(values))) + tiny


def test_round_trip_within_half_a_step():
    rng = np.random.default_rng(1)
    values = rng.gamma(2.0, 3.0, size=(64, 80))
    decoded, meta = _round_trip(values, seq=17, t=1.5e9, window=200, lag=10)
    step = (values.max() - values.min()) / 65535
    assert meta["scale"] == pytest.approx(step, rel=1e-12)
    assert np.abs(decoded - values).max() <= step / 2 + 1e-12
    assert decoded.dtype == np.float64 and decoded.shape == values.shape
    assert decoded.min() == values.min()  # the minimum is the offset: exact
    assert (meta["seq"], meta["t"], meta["window"], meta["lag"]) == (17, 1.5e9, 200, 10)
    assert meta["shape"] == [64, 80] and not meta["downsampled"]


def test_png_is_16_bit_greyscale_readable_without_edgedsm():
    import cv2

    values = np.linspace(0, 1, 300).reshape(15, 20)
    png, meta = encode_map(values, estimator="s2")
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    image = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
    assert image.dtype == np.uint16 and image.shape == (15, 20)
    assert image.min() == 0 and image.max() == 65535
    rebuilt = meta["offset"] + image * meta["scale"]
    assert np.abs(rebuilt - values).max() <= meta["scale"] / 2 + 1e-15


def test_constant_map_decodes_exactly():
    values = np.full((7, 9), 0.125)
    decoded, meta = _round_trip(values)
    assert meta["scale"] == 0.0
    assert np.array_equal(decoded, values)


def test_tiny_range_does_not_collapse():
    values = np.array([[1.0, np.nextafter(1.0, 2.0)]])
    decoded, _ = _round_trip(values)
    assert np.array_equal(decoded, values)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_values_are_refused(bad):
    values = np.ones((4, 4))
    values[2, 3] = bad
    with pytest.raises(MapCodecError, match="non-finite"):
        encode_map(values, estimator="s3")


def test_overflowing_range_is_refused():
    with pytest.raises(MapCodecError, match="overflows"):
        encode_map(np.array([[-1e308, 1e308]]), estimator="s1")


def test_bad_shapes_are_refused():
    with pytest.raises(MapCodecError, match="2-D"):
        encode_map(np.ones(5), estimator="s1")
    with pytest.raises(MapCodecError, match="2-D"):
        encode_map(np.ones((0, 4)), estimator="s1")


def test_downsampling_keeps_aspect_and_is_stated_in_meta():
    rng = np.random.default_rng(2)
    values = rng.random((400, 1000))
    decoded, meta = _round_trip(values, max_size=100)
    assert meta["downsampled"] is True
    assert meta["shape"] == [40, 100] and meta["source_shape"] == [400, 1000]
    reference = downsample_map(values, 100)
    assert np.abs(decoded - reference).max() <= _tolerance(reference, meta)
    # area averaging: each output pixel is the mean of a 10 x 10 block
    assert reference[3, 7] == pytest.approx(values[30:40, 70:80].mean())


def test_small_map_is_not_upsampled():
    values = np.arange(12.0).reshape(3, 4)
    assert downsample_map(values, 100).shape == (3, 4)


def test_mismatched_meta_is_detected():
    png_a, meta_a = encode_map(np.eye(5), estimator="s1")
    png_b, _ = encode_map(np.eye(5)[::-1], estimator="s1")
    with pytest.raises(MapCodecError, match="CRC"):
        decode_map(png_b, meta_a)
    with pytest.raises(MapCodecError, match="meta says"):
        decode_map(png_a, {**meta_a, "shape": [4, 6], "png_crc32": None})
    with pytest.raises(MapCodecError, match="not a readable PNG"):
        decode_map(b"not a png", {**meta_a, "png_crc32": None})
    with pytest.raises(MapCodecError, match="offset/scale/shape"):
        decode_map(png_a, {"format": meta_a["format"]})


def test_extra_meta_cannot_replace_codec_keys():
    _, meta = encode_map(np.eye(3), estimator="s1", extra={"frames": 5, "region_count": 2})
    assert meta["frames"] == 5
    with pytest.raises(MapCodecError, match="replace"):
        encode_map(np.eye(3), estimator="s1", extra={"scale": 1.0})


finite = st.floats(min_value=-1e12, max_value=1e12, allow_nan=False, allow_infinity=False, width=64)


@settings(max_examples=150, deadline=None)
@given(values=hnp.arrays(np.float64, hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=24),
                         elements=finite))
def test_round_trip_property(values):
    decoded, meta = _round_trip(values)
    assert np.isfinite(decoded).all()
    assert np.abs(decoded - values).max() <= _tolerance(values, meta)
    span = float(values.max()) - float(values.min())
    assert meta["scale"] <= max(span / 65535, np.finfo(np.float64).smallest_subnormal)


@settings(max_examples=60, deadline=None)
@given(values=hnp.arrays(np.float64, st.tuples(st.integers(1, 90), st.integers(1, 90)),
                         elements=st.floats(0, 1e3, width=64)),
       max_size=st.integers(1, 40))
def test_downsampled_round_trip_property(values, max_size):
    decoded, meta = _round_trip(values, max_size=max_size)
    reference = downsample_map(values, max_size)
    assert max(decoded.shape) <= max(max_size, 1)
    assert np.abs(decoded - reference).max() <= _tolerance(reference, meta)
