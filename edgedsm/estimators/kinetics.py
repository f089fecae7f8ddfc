"""Drying kinetics over decades: a region's two-time correlation at geometric ages (docs/kinetics.md).

The window estimators (S1/S2/S3 over N frames, τc up to K <= N/2) see one window; a film that
slows over decades leaves it. Multi-speckle dynamic light scattering has the tool: the
*time-resolved correlation* of Cipelletti et al., J. Phys.: Condens. Matter 15 (2003) S257
(Eq. 1; Duri et al., Phys. Rev. E 72 (2005) 051401 for its statistics). For a region of many
speckles, the degree of correlation between the frame at t and the one at t - τ,

    c(t, τ) = <I_p(t) I_p(t-τ)>_p / (<I_p(t)>_p <I_p(t-τ)>_p) - 1      (dimensionless)

averaged over the region's pixels p, needs no time average, so it follows non-stationary
dynamics frame by frame. HORUS (Formulaction; Brunel et al., "Adaptive Speckle Imaging
Interferometry", 2007) shows the same idea as a speckle rate: each new image against images of
increasing age.

What this module adds to Eq. 1 (each for a stated reason):

* **Ages on a log scale, exact.** Only the region's pixels of a few past frames are kept, at ages
  spread evenly in log age up to ``longest_age`` frames (:func:`slot_schedule`): memory
  (slots + 1) × region pixels × 4 bytes, O(region pixels) per push, O(slots × region pixels) per
  :meth:`Kinetics.measure`. Every kept frame's index is stored, so the correlation uses actual ages.
* **Dark level and illumination profile out.** Intensities are taken above the camera's dark level
  μ_dark; with ``flatten`` (default: a LOCAL_MEAN-pixel box, as the signal quality's spatial
  contrast) each pixel is divided by its frame's local mean M_p before Eq. 1 (Cipelletti et al.
  correct uneven illumination by a normalising profile; a box mean of the frame itself needs no
  time average and also removes a darkening film's fall and ambient light's uniform offset from
  the means). A static beam profile would otherwise add var(profile)/mean² to c at every age, a
  floor the 1/e criterion can never cross. ``flatten=0``: Eq. 1 exactly.
* **Normalised at short lag, noise out.** c(t, 0) is the squared speckle contrast plus the
  camera noise's share, σ_n²(I)/M² per pixel (shot and read noise, independent from frame to
  frame, so absent from every c(t, τ >= 1)). The noise model (:class:`~edgedsm.estimators.noise.NoiseModel`,
  ``variance``: K·(I - μ_dark) + σ_d², rounding included; linear in I, so one frame's values give
  its region mean unbiased) takes it out: β(t) = c(t, 0) - <σ_n²/M²>·(1 - 1/B)/<r>², B the box's
  pixel count (the pixel's own noise is 1/B of its box mean's). The normalised correlation is
  g(t, τ) = c(t, τ)/sqrt(β(t) β(t - τ)), 1 at τ -> 0 and exp(-Σ 1/τc) for the simulator's
  random-walk phase (field correlation exp(-Σ/2), Siegert: g2 - 1 = |g1|²).
* **Decorrelation time.** τ(t) is the age at which g falls to 1/e, interpolated between the two
  ages that bracket it linearly in ln(-ln g) against ln age (exact for stretched exponentials
  exp(-(τ/τ0)^p), Cipelletti's and DDM's shape); rate = 1/τ (1/frame; the caller divides by Δt).

Statuses (never a number where there is none): ``ok``; ``above`` (g still above 1/e at the
oldest age kept: τ > that age, the ``bound``); ``below`` (under 1/e at the youngest: τ < 1
frame); ``dark``, ``saturated``, ``not_speckle`` (the signal quality's bounds and words,
:mod:`edgedsm.estimators.signal_quality`, on the current frame); ``warming_up`` (no past frame yet).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from edgedsm.errors import EstimatorError
from edgedsm.estimators.noise import NoiseModel
from edgedsm.estimators.signal_quality import (
    DARK,
    DARK_MAX,
    DARK_SNR,
    LOCAL_MEAN,
    MIN_CONTRAST,
    NOT_SPECKLE,
    SATURATED,
    SATURATED_MAX,
)

OK, ABOVE, BELOW, WARMING_UP = "ok", "above", "below", "warming_up"
STATUSES = (OK, ABOVE, BELOW, DARK, SATURATED, NOT_SPECKLE, WARMING_UP)
DEFAULT_PER_OCTAVE = 4
MAX_PER_OCTAVE = 64
MAX_LONGEST_AGE = 1 << 40  # frames: far beyond any run, keeps the schedule's integers exact
THRESHOLD = math.exp(-1.0)  # τ is where g falls to 1/e (the e-folding time of exp(-τ/τc))


def slot_schedule(longest_age: int, per_octave: int = DEFAULT_PER_OCTAVE) -> tuple[np.ndarray, np.ndarray]:
    """Each slot's youngest age L_k and refresh period P_k (frames, int64 arrays).

    A cascade: slot k takes slot k-1's frame at pushes whose index is a multiple of P_k, and
    keeps it P_k pushes; slot 0 takes the previous frame at every push (L_0 = P_0 = 1). P_k is a
    multiple of P_{k-1} (so slot k-1 refreshes at the same push and hands over its frame at its
    oldest, L_{k-1} + P_{k-1} =: L_k), the largest one not above L_k·(q - 1), q = 2^(1/per_octave),
    and at least P_{k-1}. Slot k's frame is then always of age L_k .. L_k + P_k - 1, and since
    P_k <= max(1, L_k·(q - 1)) its age is within a factor q of L_k: the ages are spread evenly in
    log age (between per_octave and 2·per_octave slots an octave once P_k > 1; every age while
    L_k·(q - 1) < 2, i.e. up to 10 frames at 4 per octave), and no slot's age ever drifts.
    Slots are kept while L_k <= ``longest_age``.
    """
    longest = _integer("longest_age", longest_age, 1, MAX_LONGEST_AGE)
    per = _integer("per_octave", per_octave, 1, MAX_PER_OCTAVE)
    spread = 2.0 ** (1.0 / per) - 1.0
    lower, period = [1], [1]
    while (age := lower[-1] + period[-1]) <= longest:
        step = max(1, int(age * spread) // period[-1]) * period[-1]
        lower.append(age)
        period.append(step)
    return np.asarray(lower, np.int64), np.asarray(period, np.int64)


def _integer(name: str, value: object, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or not low <= value <= high:
        raise EstimatorError(f"{name} must be an integer in [{low}, {high}], got {value!r}")
    return int(value)


@dataclass(frozen=True)
class Correlation:
    """The current frame's correlation with every kept frame: ``ages`` (frames, increasing),
    ``c`` (Eq. 1), ``g`` (normalised, NaN where a frame has no speckle contrast) and ``beta``
    the current frame's noise-free zero-lag c (squared speckle contrast)."""

    frame: int
    ages: np.ndarray
    c: np.ndarray
    g: np.ndarray
    beta: float


@dataclass(frozen=True)
class KineticsResult:
    """τ (frames) and rate 1/τ (1/frame), or None with a status other than ``ok``; ``bound``:
    the age (frames) τ is above (``above``) or below (``below``), else None."""

    frame: int
    status: str
    tau: float | None
    rate: float | None
    bound: float | None
    correlation: Correlation | None


class Kinetics:
    """A region's reference frames at geometric ages and its decorrelation time (module docstring).

    ``mask``: boolean (H, W), the region; ``noise``: the camera's noise model (DN); ``longest_age``
    and ``per_octave``: :func:`slot_schedule`; ``top``: full scale (DN; default the integer
    dtype's maximum, none for float frames); ``flatten``: the local-mean box side in pixels (odd,
    >= 3), 0 for Eq. 1 as written. Push every frame in order (:meth:`push`, O(region pixels));
    :meth:`measure` when a value is wanted (O(slots × region pixels)).
    """

    def __init__(self, mask: np.ndarray, noise: NoiseModel, longest_age: int,
                 per_octave: int = DEFAULT_PER_OCTAVE, top: float | None = None,
                 flatten: int = LOCAL_MEAN) -> None:
        region = np.asarray(mask)
        if region.dtype != np.bool_ or region.ndim != 2 or not region.any():
            raise EstimatorError("mask must be a non-empty boolean (H, W) array")
        if not isinstance(noise, NoiseModel):
            raise EstimatorError(f"noise must be a NoiseModel, got {type(noise).__name__}")
        if top is not None and (isinstance(top, bool) or not isinstance(top, int | float)
                                or not math.isfinite(top) or top <= 0):
            raise EstimatorError(f"top must be a finite grey level > 0, got {top!r}")
        box = _integer("flatten", flatten, 0, 255)
        if box and (box < 3 or box % 2 == 0):
            raise EstimatorError(f"flatten must be 0 or an odd box side >= 3, got {flatten}")
        self.lower, self.period = slot_schedule(longest_age, per_octave)
        self.longest_age = int(longest_age)
        self.shape = region.shape
        self.noise = noise
        self.top = top
        self.flatten = box
        rows, cols = np.flatnonzero(region.any(axis=1)), np.flatnonzero(region.any(axis=0))
        half = box // 2
        # the frame's pixels the local means read: the region's bounding box and half a box around
        self._outer = (max(rows[0] - half, 0), min(rows[-1] + 1 + half, region.shape[0]),
                       max(cols[0] - half, 0), min(cols[-1] + 1 + half, region.shape[1]))
        r0, r1, c0, c1 = self._outer
        self._inner = region[r0:r1, c0:c1]
        self.pixels = int(region.sum())
        slots = self.lower.size
        self._pool = np.zeros((slots + 1, self.pixels), np.float32)  # r = (I - μ_dark)/M per pixel
        self._mean = np.zeros(slots + 1)  # <r> of each buffer's frame
        self._beta = np.zeros(slots + 1)  # noise-free c(t, 0) of each buffer's frame
        self._index = np.full(slots + 1, -1, np.int64)  # frame index of each buffer's frame
        self._slot = np.full(slots, -1, np.int64)  # buffer of each slot (-1: empty)
        self._current = -1  # buffer of the newest frame
        self._verdict = WARMING_UP  # the newest frame's signal quality (OK if usable)
        self.frames_seen = 0

    @property
    def memory_bytes(self) -> int:
        """Bytes of kept pixels: (slots + 1) × region pixels × 4."""
        return int(self._pool.nbytes)

    def ages(self) -> np.ndarray:
        """Actual ages (frames) of the kept frames, slot order (increasing); empty slots left out."""
        filled = self._slot[self._slot >= 0]
        return (self.frames_seen - 1) - self._index[filled]

    def push(self, frame: np.ndarray) -> None:
        """Take the next frame (2-D, the mask's shape, intensities >= 0 in DN)."""
        image = np.asarray(frame)
        if image.shape != self.shape or not (np.issubdtype(image.dtype, np.integer)
                                             or np.issubdtype(image.dtype, np.floating)):
            raise EstimatorError(f"frame must be a numeric {self.shape} array, got {image.dtype} {image.shape}")
        r0, r1, c0, c1 = self._outer
        window = image[r0:r1, c0:c1]
        if np.issubdtype(window.dtype, np.floating) and not np.isfinite(window).all():
            raise EstimatorError("frame contains NaN or inf")
        buffer = self._advance()
        self._verdict = self._store(window, buffer)

    def _advance(self) -> int:
        """The cascade of :func:`slot_schedule` for push number n = frames_seen: slots 0..K-1
        (those whose period divides n, a prefix) take the next younger slot's frame, slot 0 the
        newest; the buffer the last of them let go (or a free one) takes the new frame."""
        n = self.frames_seen
        refresh = 0
        while refresh < self.period.size and n % self.period[refresh] == 0:
            refresh += 1
        released = int(self._slot[refresh - 1])
        self._slot[1:refresh] = self._slot[:refresh - 1].copy()
        self._slot[0] = self._current
        if released < 0:
            used = set(self._slot.tolist()) | {self._current}
            released = next(b for b in range(self._index.size) if b not in used)
        self._current = released
        self._index[released] = n
        self.frames_seen = n + 1
        return released

    def _store(self, window: np.ndarray, buffer: int) -> str:
        """Write the new frame's r = (I - μ_dark)/M into ``buffer`` with its <r> and β; its verdict."""
        level = window.astype(np.float64) - self.noise.dark_mean
        values = level[self._inner]
        if self.flatten:
            local, count = _box_mean(level, self.flatten)
            local, count = local[self._inner], count[self._inner]
        else:
            local, count = np.full(values.size, values.mean()), float(values.size)
        noise = self.noise.variance(values + self.noise.dark_mean)  # DN², the pixel's own level
        sigma = np.sqrt(self.noise.variance(np.maximum(local, 0.0) + self.noise.dark_mean))
        lit = local >= DARK_SNR * sigma
        top = self.top if self.top is not None else _dtype_top(window.dtype)
        saturated = float((values + self.noise.dark_mean >= top).mean()) if top is not None else 0.0
        scale = np.where(lit & (local > 0), local, np.maximum(DARK_SNR * sigma, np.finfo(float).tiny))
        ratio = values / scale
        self._pool[buffer] = ratio
        mean = float(ratio.mean())
        self._mean[buffer] = mean
        noise_share = float((noise / scale**2 * (1.0 - 1.0 / count)).mean())
        self._beta[buffer] = (float((ratio * ratio).mean()) - noise_share) / (mean * mean) - 1.0 \
            if mean > 0 else 0.0
        if saturated > SATURATED_MAX:
            return SATURATED
        if 1.0 - float(lit.mean()) > DARK_MAX or mean <= 0:
            return DARK
        if self._beta[buffer] < MIN_CONTRAST**2:
            return NOT_SPECKLE
        return OK

    def correlation(self) -> Correlation:
        """c and g of the newest frame against every kept one (module docstring)."""
        if self._current < 0:
            raise EstimatorError("no frame pushed yet")
        filled = self._slot[self._slot >= 0]
        now = self._current
        products = self._pool @ self._pool[now] / np.float32(self.pixels)  # every buffer: one gemv
        means = self._mean[filled] * self._mean[now]
        with np.errstate(divide="ignore", invalid="ignore"):
            c = np.where(means > 0, products[filled].astype(np.float64) / means - 1.0, np.nan)
            both = self._beta[filled] * self._beta[now]
            g = np.where(both > 0, c / np.sqrt(both), np.nan)
        ages = (self.frames_seen - 1) - self._index[filled]
        return Correlation(self.frames_seen - 1, ages, c, g, float(self._beta[now]))

    def measure(self) -> KineticsResult:
        """τ(t) and the rate of the newest frame, or the status that says why there is none."""
        if self._current < 0:
            raise EstimatorError("no frame pushed yet")
        frame = self.frames_seen - 1
        if self._verdict != OK:
            return KineticsResult(frame, self._verdict, None, None, None, None)
        corr = self.correlation()
        status, tau, bound = decorrelation_time(corr.ages, corr.g)
        if status == WARMING_UP:
            return KineticsResult(frame, WARMING_UP, None, None, None, corr)
        return KineticsResult(frame, status, tau, None if tau is None else 1.0 / tau, bound, corr)


def decorrelation_time(ages: np.ndarray, g: np.ndarray) -> tuple[str, float | None, float | None]:
    """(status, τ, bound) from normalised correlations ``g`` at increasing ``ages`` (frames):
    τ where g first falls below 1/e, interpolated in ln(-ln g) against ln age (linearly in g
    where g >= 1 or <= 0 at a bracket end, the noise having pushed it out of (0, 1)); NaN ages
    are skipped. ``above`` with the oldest age, ``below`` with the youngest, ``warming_up`` if none."""
    age = np.asarray(ages, np.float64)
    value = np.asarray(g, np.float64)
    if age.shape != value.shape or age.ndim != 1 or (age <= 0).any() or (np.diff(age) <= 0).any():
        raise EstimatorError("ages must be increasing positive frames, one per correlation")
    valid = np.isfinite(value)
    age, value = age[valid], value[valid]
    if age.size == 0:
        return WARMING_UP, None, None
    under = np.flatnonzero(value < THRESHOLD)
    if under.size == 0:
        return ABOVE, None, float(age[-1])
    i = int(under[0])
    if i == 0:
        return BELOW, None, float(age[0])
    a0, a1, g0, g1 = math.log(age[i - 1]), math.log(age[i]), value[i - 1], value[i]
    if g1 > 0.0 and g0 < 1.0:
        y0, y1 = math.log(-math.log(g0)), math.log(-math.log(g1))  # ln(-ln 1/e) = 0
        share = -y0 / (y1 - y0)
    else:
        share = (g0 - THRESHOLD) / (g0 - g1)
    return OK, math.exp(a0 + share * (a1 - a0)), None


def _box_mean(image: np.ndarray, side: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean of ``image`` over a ``side`` × ``side`` box about every pixel, and each box's pixel
    count (boxes cut at the image's edge average what they cover), by a summed-area table."""
    half = side // 2
    height, width = image.shape
    table = np.zeros((height + 1, width + 1))
    np.cumsum(np.cumsum(image, axis=0), axis=1, out=table[1:, 1:])
    top = np.clip(np.arange(height) - half, 0, height)
    bottom = np.clip(np.arange(height) + half + 1, 0, height)
    left = np.clip(np.arange(width) - half, 0, width)
    right = np.clip(np.arange(width) + half + 1, 0, width)
    total = (table[bottom][:, right] - table[top][:, right] - table[bottom][:, left] + table[top][:, left])
    count = (bottom - top)[:, None] * (right - left)[None, :]
    return total / count, count.astype(np.float64)


def _dtype_top(dtype: np.dtype) -> float | None:
    return float(np.iinfo(dtype).max) if np.issubdtype(dtype, np.integer) else None
