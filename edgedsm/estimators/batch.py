"""Reference (batch) estimators S1, S2, S3 of the paper, in float64.

All take a stack of N frames, shape (N, H, W), and a time lag m (in frames, 1 <= m <= N-1),
and return an (H, W) float64 map. Intensities are in whatever unit the frames carry (grey
levels for camera data); S1 then has that unit, S2 and S3 are dimensionless.

Intensities must be finite and >= 0 (refused otherwise: a negative value could push S2
above its maximum of 1).

Degenerate cases (defined, never NaN or inf):
- S2 with q = 0 and both intensities 0: the pair contributes 0 (no fluctuation).
- S3 where σ = 0 (constant or saturated pixel): S3 = 0. σ = 0 means every intensity of the
  window is equal, so every |difference| is 0 as well.
"""

from __future__ import annotations

import numpy as np

from edgedsm.errors import EstimatorError


def check_frames(frames: np.ndarray) -> np.ndarray:
    """Validate a (N, H, W) stack of finite, non-negative intensities; returns it as an ndarray."""
    stack = np.asarray(frames)
    if stack.ndim != 3:
        raise EstimatorError(f"frames must be a (N, H, W) stack, got shape {stack.shape}")
    if not (np.issubdtype(stack.dtype, np.integer) or np.issubdtype(stack.dtype, np.floating)):
        raise EstimatorError(f"frames must be integer or float, got {stack.dtype}")
    check_intensities(stack)
    return stack


def check_stack(frames: np.ndarray, lag: int) -> np.ndarray:
    """Validate a (N, H, W) stack and a lag; returns the stack as an ndarray."""
    stack = check_frames(frames)
    if isinstance(lag, bool) or not isinstance(lag, int | np.integer):
        raise EstimatorError(f"lag must be an integer number of frames, got {lag!r}")
    n = stack.shape[0]
    if not 1 <= lag <= n - 1:
        raise EstimatorError(f"lag m={lag} does not fit a window of N={n} frames (need 1 <= m <= N-1)")
    return stack


def check_intensities(stack: np.ndarray) -> None:
    """Refuse NaN, inf and negative intensities: a light intensity is finite and >= 0 (S2's
    |a-b|/(a+b+q) <= 1 and every other bound rests on that)."""
    if np.issubdtype(stack.dtype, np.floating) and not np.isfinite(stack).all():
        raise EstimatorError("frames contain NaN or inf (intensities must be finite and >= 0)")
    if np.issubdtype(stack.dtype, np.signedinteger) or np.issubdtype(stack.dtype, np.floating):
        lowest = stack.min() if stack.size else 0
        if lowest < 0:
            raise EstimatorError(f"frames contain a negative intensity ({lowest}); intensities must be >= 0")


def _check_q(q: float) -> float:
    q = float(q)
    if not np.isfinite(q) or q < 0:
        raise EstimatorError(f"q must be a finite number >= 0, got {q}")
    return q


def _pair_sums(stack: np.ndarray, lag: int, q: float | None) -> tuple[np.ndarray, np.ndarray | None]:
    """Σ|I_i - I_{i+m}| and, if q is given, Σ|I_i - I_{i+m}|/(I_i + I_{i+m} + q), float64."""
    n, h, w = stack.shape
    flat = stack.reshape(n, h * w)
    abs_sum = np.zeros(h * w, np.float64)
    ratio_sum = None if q is None else np.zeros(h * w, np.float64)
    for i in range(n - lag):
        a = flat[i].astype(np.float64)
        b = flat[i + lag].astype(np.float64)
        diff = np.abs(a - b)
        abs_sum += diff
        if ratio_sum is not None:
            denominator = a + b + q
            np.divide(diff, denominator, out=diff, where=denominator > 0)
            diff[denominator <= 0] = 0.0
            ratio_sum += diff
    return abs_sum.reshape(h, w), None if ratio_sum is None else ratio_sum.reshape(h, w)


def s1(frames: np.ndarray, lag: int) -> np.ndarray:
    """Eq. 1: S1 = 1/(N-m) Σ_{i=1}^{N-m} |I_i - I_{i+m}| (modified structure function).

    Args:
        frames: (N, H, W) stack of N >= 2 frames, any integer or float dtype, finite and >= 0;
            intensities in the frames' unit (grey levels for camera data).
        lag: m, in frames (an int, 1 <= m <= N-1).

    Returns:
        (H, W) float64 map in the frames' unit (grey levels), >= 0.

    Example:
        >>> import numpy as np
        >>> frames = np.array([[[0]], [[4]], [[2]]], np.uint8)   # N=3 frames of 1x1 px
        >>> s1(frames, 1)                                         # (|0-4| + |4-2|) / 2
        array([[3.]])
    """
    stack = check_stack(frames, lag)
    abs_sum, _ = _pair_sums(stack, lag, None)
    return abs_sum / (stack.shape[0] - lag)


def s2(frames: np.ndarray, lag: int, q: float = 0.0) -> np.ndarray:
    """Eq. 2: S2 = 1/(N-m) Σ |I_i - I_{i+m}| / (I_i + I_{i+m} + q); q >= 0 avoids 0/0.

    Args:
        frames: (N, H, W) stack of N >= 2 frames, any integer or float dtype, finite and >= 0.
        lag: m, in frames (an int, 1 <= m <= N-1).
        q: added to each pair's sum, in the frames' unit (grey levels); 0 counts a pair of two
            zeros as 0 (no fluctuation).

    Returns:
        (H, W) float64 map, dimensionless, in [0, 1].

    Example:
        >>> import numpy as np
        >>> s2(np.array([[[1]], [[3]], [[1]]], np.uint8), 1)      # (2/4 + 2/4) / 2
        array([[0.5]])
    """
    stack = check_stack(frames, lag)
    _, ratio_sum = _pair_sums(stack, lag, _check_q(q))
    return ratio_sum / (stack.shape[0] - lag)


def temporal_sigma(frames: np.ndarray) -> np.ndarray:
    """Eq. 4: σ with the 1/N (population) normalisation: (N, H, W) frames in, an (H, W) float64
    map out, in the frames' unit (grey levels).

    Integer data: N·ΣI² - (ΣI)² is formed exactly in integers (no cancellation), then
    σ = sqrt(that)/N; for windows too long for int64 the deviations N·I - ΣI (exact integers)
    are squared and summed in float64. Float data: two-pass, mean-centred.
    """
    stack = np.asarray(frames)
    n = stack.shape[0]
    if np.issubdtype(stack.dtype, np.integer) and stack.dtype.itemsize <= 2:
        flat = stack.reshape(n, -1)
        top = int(np.iinfo(stack.dtype).max)
        total = np.zeros(flat.shape[1], np.int64)
        for frame in flat:
            total += frame
        if n * top <= 2**32:
            # N·ΣI² - (ΣI)² = N²σ² <= (N·max/2)² < 2^63: exact in int64 even where N·ΣI² itself
            # wraps around, because numpy's integer arithmetic is modulo 2^64 and the difference
            # fits (N <= 65537 frames of 16-bit data)
            total_sq = np.zeros(flat.shape[1], np.int64)
            for frame in flat:
                f = frame.astype(np.int64)
                total_sq += f * f
            spread = n * total_sq - total * total
            return (np.sqrt(spread.astype(np.float64)) / n).reshape(stack.shape[1:])
        # longer windows: d = N·I - ΣI is an exact integer (< 2^53); σ² = Σd²/N³ sums positive
        # terms only, so it cannot cancel (relative error <= N·2^-53)
        spread_f = np.zeros(flat.shape[1], np.float64)
        for frame in flat:
            d = (n * frame.astype(np.int64) - total).astype(np.float64)
            spread_f += d * d
        return (np.sqrt(spread_f / n) / n).reshape(stack.shape[1:])
    data = stack.astype(np.float64)
    centred = data - data.mean(axis=0)
    return np.sqrt((centred * centred).mean(axis=0))


def s3(frames: np.ndarray, lag: int) -> np.ndarray:
    """Eq. 3-4: S3 = S1/σ with σ of Eq. 4 over the same N frames; S3 = 0 where σ = 0.

    Args:
        frames: (N, H, W) stack of N >= 2 frames, any integer or float dtype, finite and >= 0.
        lag: m, in frames (an int, 1 <= m <= N-1).

    Returns:
        (H, W) float64 map, dimensionless (S1 and σ share the frames' unit), >= 0.

    Example:
        >>> import numpy as np
        >>> s3(np.array([[[0]], [[4]], [[2]]], np.uint8), 1)      # S1 = 3, σ = 1.633 grey levels
        array([[1.83711731]])
    """
    stack = check_stack(frames, lag)
    abs_sum, _ = _pair_sums(stack, lag, None)
    sigma = temporal_sigma(stack)
    result = np.zeros_like(abs_sum)
    np.divide(abs_sum / (stack.shape[0] - lag), sigma, out=result, where=sigma > 0)
    return result


def all_maps(frames: np.ndarray, lag: int, q: float = 0.0) -> dict[str, np.ndarray]:
    """S1, S2 and S3 in one pass over the stack: ``{"s1", "s2", "s3"}`` -> (H, W) float64 maps
    equal to :func:`s1`, :func:`s2` (with ``q``) and :func:`s3` of the same (N, H, W) frames."""
    stack = check_stack(frames, lag)
    abs_sum, ratio_sum = _pair_sums(stack, lag, _check_q(q))
    pairs = stack.shape[0] - lag
    s1_map = abs_sum / pairs
    sigma = temporal_sigma(stack)
    s3_map = np.zeros_like(s1_map)
    np.divide(s1_map, sigma, out=s3_map, where=sigma > 0)
    return {"s1": s1_map, "s2": ratio_sum / pairs, "s3": s3_map}
