"""The streaming engine's checks at its boundary: its arguments (shape, integers, q, the maps asked
for against the registry's statements of modes and q) and each frame pushed (shape, dtype, bit
depth, layout). Pure: nothing is changed, a bad value raises EstimatorError (arguments) or
FrameError (frames) naming it. :class:`edgedsm.estimators.engine_base.SlidingWindow` calls them
before it keeps anything; a new argument or descriptor adds its check here."""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

import numpy as np

from edgedsm.errors import EstimatorError, FrameError
from edgedsm.estimators.registry import PAIR_SUM, get, names
from edgedsm.frames import sample_dtype

#: The engine's multi-band map (a (K, H, W) map of the powers in ``bands``; no registry record).
BANDS = "bands"


def estimator_names() -> tuple[str, ...]:
    """Names of the maps the engine can keep, in the order of its maps: every registry record that
    streams (edgedsm.estimators.registry: the paper's S1-S3 and τc, the field's descriptors of
    docs/descriptors.md, the frequency bands), and "bands"."""
    return (*names(streams=True), BANDS)


def check_int(name: str, value: Any, low: int, high: int) -> int:
    """``value`` as an int within [low, high] (a bool or a float is refused)."""
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        raise EstimatorError(f"{name} must be an integer, got {value!r}")
    if not low <= value <= high:
        raise EstimatorError(f"{name} must be in [{low}, {high}], got {value}")
    return int(value)


def check_shape(shape: Any) -> tuple[int, int]:
    """(height, width) in pixels, each 1..2^31."""
    try:
        dims = tuple(shape)
    except TypeError:
        raise EstimatorError(f"shape must be (height, width), got {shape!r}") from None
    if len(dims) != 2:
        raise EstimatorError(f"shape must be (height, width), got {shape!r}")
    return (check_int("height", dims[0], 1, 2**31), check_int("width", dims[1], 1, 2**31))


def check_q(q: Any) -> float:
    """Eq. 2's constant q (grey levels): a finite number >= 0."""
    if isinstance(q, bool) or not isinstance(q, int | float | np.integer | np.floating):
        raise EstimatorError(f"q must be a number, got {q!r}")
    if not (math.isfinite(q) and q >= 0):
        raise EstimatorError(f"q must be a finite number >= 0, got {q}")
    return float(q)


def check_estimators(estimators: Iterable[str] | str) -> tuple[str, ...]:
    """The maps asked for, a non-empty subset of :func:`estimator_names`, in its order."""
    asked = (estimators,) if isinstance(estimators, str) else tuple(estimators)
    known = estimator_names()
    unknown = [name for name in asked if name not in known]
    if unknown or not asked:
        raise EstimatorError(f"estimators must be a non-empty subset of {known}, got {estimators!r}")
    return tuple(name for name in known if name in asked)


def check_maps(estimators: Iterable[str], mode: str, q: float, window: int) -> None:
    """The registry's statements about the maps asked for: each is formed in ``mode``, one formed at
    q = 0 (Fujii) gets q = 0, and GD's exact int64 pair sum holds C(N, 2) differences of 16-bit data."""
    for name in estimators:
        record = None if name == BANDS else get(name)
        if record is not None and (problem := record.mode_problem(mode)):
            raise EstimatorError(f"estimator {name!r}: {problem}")
        if record is not None and record.needs_q_zero and q != 0.0:
            raise EstimatorError(f"estimator {name!r} is {record.summary} (BSLTL's {record.bsltl}.m): construct "
                                 f"the engine with q=0, got q={q}")
        if record is not None and record.source == "pair_sum" and window * (window - 1) // 2 * 65535 > 2**63 - 1:
            raise EstimatorError(f"estimator {PAIR_SUM!r}: a window of {window} frames overflows its int64 sum")


def check_frame(frame: Any, shape: tuple[int, int], bits: int | None) -> int:
    """One frame for an engine of ``shape`` whose data are ``bits``-bit (None: not known yet, the
    frame's dtype says: uint8 8, uint16 16); returns the frame's bit depth."""
    if not isinstance(frame, np.ndarray):
        raise FrameError(f"a frame must be a numpy array, got {type(frame).__name__}")
    if frame.shape != shape:
        raise FrameError(f"frame shape {frame.shape} does not match the engine's {shape}")
    if bits is not None:
        expected = sample_dtype(bits)
        if frame.dtype != expected:
            raise FrameError(f"frame dtype {frame.dtype} is not {expected} (the engine takes {bits}-bit data)")
    elif frame.dtype == np.dtype(np.uint8):
        bits = 8
    elif frame.dtype == np.dtype(np.uint16):
        bits = 16
    else:
        raise FrameError(f"frame dtype {frame.dtype} is not uint8 or uint16 (native byte order)")
    if not frame.flags.c_contiguous:
        raise FrameError("frame is not C-contiguous (pass np.ascontiguousarray(frame))")
    if bits < 8 * frame.dtype.itemsize:
        top = int(frame.max())
        if top > (1 << bits) - 1:
            raise FrameError(f"frame value {top} is above the {bits}-bit range 0..{(1 << bits) - 1}")
    return bits
