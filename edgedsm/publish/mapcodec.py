"""Activity maps as 16-bit PNG + a JSON meta dict, rebuilt by a subscriber within one step.

Encoding (pure, no I/O): the float map ``x`` (optionally downsampled by area averaging to fit
``max_size``) is quantized linearly onto 0..65535::

    offset = min(x),  scale = (max(x) - min(x)) / 65535,  q = rint((x - offset) / scale)

and ``q`` is written as a 16-bit greyscale PNG (lossless). A subscriber rebuilds
``x' = offset + q * scale``, so ``|x' - x| <= scale / 2`` (half a quantization step; float64
rounding adds ~1e-16 relative). The meta carries ``offset`` and ``scale`` as exact JSON floats.

Degenerate cases: a constant map has ``scale = 0`` and all ``q = 0``; it decodes exactly to
``offset``. Non-finite values (NaN, inf) are refused: the estimators never produce them, so one
here is a bug upstream and must not be papered over. A decoded map is always finite.

Anyone can decode without edgedsm: read the PNG as 16-bit (OpenCV ``IMREAD_UNCHANGED``, Pillow
mode ``I;16``), then ``offset + q * scale``; check ``png_crc32`` (zlib CRC-32 of the PNG bytes)
to pair a PNG with its meta.
"""

from __future__ import annotations

import math
import zlib
from collections.abc import Mapping
from typing import Any

import cv2
import numpy as np

from edgedsm.publish.errors import MapCodecError

FORMAT = "png16-linear"
FORMAT_VERSION = 1
LEVELS = 65535  # largest 16-bit code


def downsample_map(values: np.ndarray, max_size: int | None) -> np.ndarray:
    """The map reduced by area averaging so that its longest side is at most ``max_size``.

    Aspect ratio is kept (each side rounded, at least 1 pixel). Returned unchanged (as float64)
    when it already fits or ``max_size`` is None.
    """
    data = np.asarray(values, dtype=np.float64)
    if data.ndim != 2 or 0 in data.shape:
        raise MapCodecError(f"a map must be a non-empty 2-D array, got shape {data.shape}")
    if max_size is None or max(data.shape) <= max_size:
        return data
    if max_size < 1:
        raise MapCodecError(f"max_size must be >= 1, got {max_size}")
    factor = max_size / max(data.shape)
    height = max(1, round(data.shape[0] * factor))
    width = max(1, round(data.shape[1] * factor))
    # INTER_AREA = mean over each target pixel's footprint: the right filter for activity maps
    # (no ringing, no invented extremes).
    return cv2.resize(np.ascontiguousarray(data), (width, height), interpolation=cv2.INTER_AREA)


def encode_map(values: np.ndarray, *, estimator: str, seq: int | None = None, t: float | None = None,
               window: int | None = None, lag: int | None = None, max_size: int | None = None,
               compression: int = 3, extra: Mapping[str, Any] | None = None) -> tuple[bytes, dict[str, Any]]:
    """Encode a float map: ``(png_bytes, meta)``; ``meta`` is JSON-ready.

    ``estimator`` names the map (``s1``, ``s2``, ``s3``); ``seq`` is the frame sequence number
    the map belongs to, ``t`` its time (s since the epoch), ``window`` and ``lag`` the
    estimator's N and m (frames). ``extra`` is merged into the meta (it may not replace the
    codec's own keys).
    """
    source = np.asarray(values)
    data = downsample_map(source, max_size)
    if not np.isfinite(data).all():
        bad = int(np.count_nonzero(~np.isfinite(data)))
        raise MapCodecError(f"map {estimator!r} has {bad} non-finite value(s) (NaN or inf); refusing to "
                            "publish it (the estimators define every degenerate case, so this is a bug)")
    if not 0 <= compression <= 9:
        raise MapCodecError(f"PNG compression must be 0..9, got {compression}")
    low, high = float(data.min()), float(data.max())
    span = high - low
    if not math.isfinite(span):
        raise MapCodecError(f"map {estimator!r} spans {low!r}..{high!r}: the range overflows float64")
    # A range too small for span / 65535 to be representable takes the smallest positive float
    # as its step, so a non-constant map never collapses to its minimum.
    scale = max(span / LEVELS, math.ulp(0.0)) if span > 0 else 0.0
    if scale > 0:
        codes = np.rint((data - low) / scale)
        np.clip(codes, 0, LEVELS, out=codes)
        quantized = codes.astype(np.uint16)
    else:  # constant map: all codes 0, decodes exactly to `low`
        quantized = np.zeros(data.shape, np.uint16)
    ok, buffer = cv2.imencode(".png", quantized, [cv2.IMWRITE_PNG_COMPRESSION, int(compression)])
    if not ok:
        raise MapCodecError(f"OpenCV could not encode map {estimator!r} as PNG")
    png = buffer.tobytes()
    meta: dict[str, Any] = {
        "format": FORMAT,
        "version": FORMAT_VERSION,
        "estimator": estimator,
        "dtype": "float64",
        "shape": [int(data.shape[0]), int(data.shape[1])],
        "source_shape": [int(source.shape[0]), int(source.shape[1])],
        "downsampled": data.shape != source.shape,
        "offset": low,
        "scale": scale,
        "min": low,
        "max": high,
        "quantization_step": scale,
        "seq": seq,
        "t": t,
        "window": window,
        "lag": lag,
        "png_bytes": len(png),
        "png_crc32": zlib.crc32(png),
    }
    if extra:
        clash = sorted(set(extra) & set(meta))
        if clash:
            raise MapCodecError(f"extra meta keys {clash} would replace the codec's own")
        meta.update(extra)
    return png, meta


def decode_map(png: bytes, meta: Mapping[str, Any]) -> np.ndarray:
    """Rebuild the float64 map from the PNG bytes and their meta (see the module docstring)."""
    if meta.get("format", FORMAT) != FORMAT:
        raise MapCodecError(f"unknown map format {meta.get('format')!r} (this decoder reads {FORMAT!r})")
    crc = meta.get("png_crc32")
    if crc is not None and zlib.crc32(png) != crc:
        raise MapCodecError("the PNG does not belong to this meta (CRC-32 differs): "
                            "a map and a meta of different updates were paired")
    try:
        offset, scale = float(meta["offset"]), float(meta["scale"])
        shape = tuple(int(v) for v in meta["shape"])
    except (KeyError, TypeError, ValueError) as exc:
        raise MapCodecError(f"map meta lacks a valid offset/scale/shape: {exc}") from None
    if not (math.isfinite(offset) and math.isfinite(scale) and scale >= 0):
        raise MapCodecError(f"map meta has an invalid offset {offset!r} or scale {scale!r}")
    image = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise MapCodecError("payload is not a readable PNG")
    if image.dtype != np.uint16 or image.ndim != 2:
        raise MapCodecError(f"expected a 16-bit greyscale PNG, got {image.dtype} with shape {image.shape}")
    if image.shape != shape:
        raise MapCodecError(f"PNG is {image.shape[0]}x{image.shape[1]} but the meta says {shape[0]}x{shape[1]}")
    return offset + image.astype(np.float64) * scale
