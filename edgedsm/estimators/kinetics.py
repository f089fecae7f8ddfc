"""Drying kinetics over decades: a region's two-time correlation at geometric ages (docs/kinetics.md).

The window estimators (S1/S2/S3 over N frames, τc up to K <= N/2) see one window; a film that
slows over decades leaves it. Multi-speckle dynamic light scattering has the tool: the
*time-resolved correlation* of Cipelletti et al., J. Phys.: Condens. Matter 15 (2003) S257
(Duri et al., Phys. Rev. E 72 (2005) 051401 for its statistics). For a region of many speckles,
their degree of correlation between the frame at t and the one at t - τ,

    c(t, τ) = <I_p(t) I_p(t-τ)>_p / (<I_p(t)>_p <I_p(t-τ)>_p) - 1      (Eq. 1 here; dimensionless)

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
* **A white step, when asked.** Phase noise and vibration (the seed paper's environmental noise)
  lower every c(t, τ >= 1) alike, which no camera noise model sees; ``measure(white=True)`` divides
  g by its extrapolation to age 0 (:func:`white_step`) first.

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
from edgedsm.estimators.kinetics_numba import fused_store
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
KERNELS = ("auto", "numpy", "numba")
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
    the age (frames) τ is above (``above``) or below (``below``), else None; ``amplitude``: what g
    was divided by (1, or :func:`white_step`'s A when asked)."""

    frame: int
    status: str
    tau: float | None
    rate: float | None
    bound: float | None
    correlation: Correlation | None
    amplitude: float = 1.0


class Kinetics:
    """A region's reference frames at geometric ages and its decorrelation time (module docstring).

    ``mask``: boolean (H, W), the region; ``noise``: the camera's noise model (DN); ``longest_age``
    and ``per_octave``: :func:`slot_schedule`; ``top``: full scale (DN; default the integer
    dtype's maximum, none for float frames); ``flatten``: the local-mean box side in pixels (odd,
    >= 3), 0 for Eq. 1 as written; ``kernel``: "auto" (the fused numba pass of
    :mod:`edgedsm.estimators.kinetics_numba` for flattened integer frames when numba is installed,
    else NumPy), "numpy" or "numba". Push every frame in order (:meth:`push`, O(region pixels));
    :meth:`measure` when a value is wanted (O(slots × region pixels)).
    """

    def __init__(self, mask: np.ndarray, noise: NoiseModel, longest_age: int,
                 per_octave: int = DEFAULT_PER_OCTAVE, top: float | None = None,
                 flatten: int = LOCAL_MEAN, kernel: str = "auto") -> None:
        region = np.asarray(mask)
        if region.dtype != np.bool_ or region.ndim != 2 or not region.any():
            raise EstimatorError("mask must be a non-empty boolean (H, W) array")
        if not isinstance(noise, NoiseModel):
            raise EstimatorError(f"noise must be a NoiseModel, got {type(noise).__name__}")
        if top is not None and (isinstance(top, bool) or not isinstance(top, int | float)
                                or not math.isfinite(top) or top <= 0):
            raise EstimatorError(f"top must be a finite grey level > 0, got {top!r}")
        if kernel not in KERNELS:
            raise EstimatorError(f"kernel must be one of {KERNELS}, got {kernel!r}")
        box = _integer("flatten", flatten, 0, 255)
        if box and (box < 3 or box % 2 == 0):
            raise EstimatorError(f"flatten must be 0 or an odd box side >= 3, got {flatten}")
        self.lower, self.period = slot_schedule(longest_age, per_octave)
        self.longest_age = int(longest_age)
        self.shape = region.shape
        self.noise = noise
        self.top = top
        self.flatten = box
        # the fused pass where it applies (flattened integer frames) and numba is installed
        self._fused = fused_store() if box and kernel != "numpy" else None
        if kernel == "numba" and self._fused is None:
            raise EstimatorError("kernel 'numba' needs numba (the optional extra 'fast') and flatten > 0")
        self._layout = _Layout(region, box)
        self.pixels = self._layout.pixels
        self._dark_level = _lit_level(noise)  # DN above μ_dark: DARK_SNR noise σ
        self._luts: dict[np.dtype, tuple[np.ndarray, float | None]] = {}
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
        if not np.issubdtype(image.dtype, np.unsignedinteger):
            outer = self._layout.outer(image)
            if np.issubdtype(image.dtype, np.floating) and not np.isfinite(outer).all():
                raise EstimatorError("frame contains NaN or inf")
            if outer.size and outer.min() < 0:
                raise EstimatorError("frame contains a negative intensity (intensities must be >= 0)")
        buffer = self._advance()
        self._verdict = self._store(image, buffer)

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

    def _store(self, image: np.ndarray, buffer: int) -> str:
        """Write the new frame's r = (I - μ_dark)/M into ``buffer`` with its <r> and β; its verdict."""
        layout, dark = self._layout, self.noise.dark_mean
        lut, top = self._lut(image.dtype)
        count = float(self.pixels)
        if self._fused is not None and lut is not None:
            total, squares, noise_sum, lit, saturated = self._fused(
                layout.outer(image), layout.rows.start - layout.outer_rows.start,
                layout.cols.start - layout.outer_cols.start, layout.row_low, layout.row_high, layout.col_low,
                layout.col_high, layout.inner, layout.full, float(dark), lut, self._dark_level,
                math.inf if top is None else float(top), self._pool[buffer])
        else:
            total, squares, noise_sum, lit, saturated = self._sums(image, lut, top, self._pool[buffer])
        mean = total / count
        self._mean[buffer] = mean
        self._beta[buffer] = ((squares - noise_sum) / count) / (mean * mean) - 1.0 if mean > 0 else 0.0
        if saturated > SATURATED_MAX * count:
            return SATURATED
        if lit < (1.0 - DARK_MAX) * (count if self.flatten else 1.0) or mean <= 0:
            return DARK
        if self._beta[buffer] < MIN_CONTRAST**2:
            return NOT_SPECKLE
        return OK

    def _sums(self, image: np.ndarray, lut: np.ndarray | None, top: float | None,
              out: np.ndarray) -> tuple[float, float, float, int, int]:
        """The NumPy path of the push: r into ``out``; Σr, Σr², Σ σ²(I)·(1 - 1/B)/M², the lit
        pixels (or 0/1 for the region's mean without flattening) and the saturated ones."""
        layout, dark = self._layout, self.noise.dark_mean
        values = layout.values(image)  # the region's pixels, DN, the frame's dtype
        level = values - dark
        local = layout.local_means(image) - dark if self.flatten else np.float64(level.mean())
        noise = self.noise.variance(values) if lut is None else lut[values]  # DN², each pixel's own level
        lit = local > self._dark_level
        inverse = 1.0 / np.where(lit, local, self._dark_level)
        ratio = level * inverse
        out[:] = ratio
        # sums, not BLAS dot products: OpenBLAS wakes its threads for a long vector, and on a busy
        # machine waiting for them cost more than the products (37 ms a 256² push, against 3)
        noise_sum = float((noise * layout.shrink * inverse * inverse).sum()) if self.flatten \
            else float(noise.sum()) * layout.shrink * float(inverse) ** 2
        saturated = 0 if top is None else int(np.count_nonzero(values >= top))
        return float(ratio.sum()), float((ratio * ratio).sum()), noise_sum, int(np.count_nonzero(lit)), saturated

    def _lut(self, dtype: np.dtype) -> tuple[np.ndarray | None, float | None]:
        """The noise variance of every grey level of an integer dtype (None for floats: computed per
        pixel) and the full scale, made once per dtype."""
        if dtype not in self._luts:
            integer = np.issubdtype(dtype, np.integer)
            top = self.top if self.top is not None else (float(np.iinfo(dtype).max) if integer else None)
            table = np.issubdtype(dtype, np.unsignedinteger) and dtype.itemsize <= 2  # 8 to 16-bit cameras
            lut = self.noise.variance(np.arange(np.iinfo(dtype).max + 1.0)) if table else None
            self._luts[dtype] = (lut, top)
        return self._luts[dtype]

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

    def measure(self, white: bool = False) -> KineticsResult:
        """τ(t) and the rate of the newest frame, or the status that says why there is none.
        ``white``: take a white step out of g first (:func:`white_step`), for phase noise or
        vibration that decorrelates the frames within one interval."""
        if self._current < 0:
            raise EstimatorError("no frame pushed yet")
        frame = self.frames_seen - 1
        if self._verdict != OK:
            return KineticsResult(frame, self._verdict, None, None, None, None)
        corr = self.correlation()
        amplitude = white_step(corr.ages, corr.g) if white else 1.0
        status, tau, bound = decorrelation_time(corr.ages, corr.g / amplitude)
        if status == WARMING_UP:
            return KineticsResult(frame, WARMING_UP, None, None, None, corr, amplitude)
        return KineticsResult(frame, status, tau, None if tau is None else 1.0 / tau, bound, corr, amplitude)


def white_step(ages: np.ndarray, g: np.ndarray) -> float:
    """The amplitude A in (0, 1] that g extrapolates to at age 0 from its two youngest ages a0 < a1,
    as an exponential decay A·exp(-a/τ) does: ln A = (a1 ln g(a0) - a0 ln g(a1))/(a1 - a0), kept
    between g(a0) (a decay's intercept is at least its first value: g rising from a0 to a1 is noise)
    and 1; 1 where either is not positive.

    Camera noise is out of c(t, 0) already; what else lowers every c(t, τ >= 1) alike is a phase
    that changes independently from frame to frame (white phase noise, vibration: the seed paper's
    environmental noise, §2A): g = A·exp(-Σ) with A = exp(-2σ²) for phase noise of σ rad. Exact for
    exponential decays at any rate; a stretched one (exp(-(a/τ)^p), p < 1) decays fastest at the
    shortest ages and is read as a step too (τ long), so it is asked for, not the default."""
    age, value = _valid(ages, g)
    if age.size < 2 or value[0] <= 0 or value[1] <= 0:
        return 1.0
    log_amplitude = (age[1] * math.log(value[0]) - age[0] * math.log(value[1])) / (age[1] - age[0])
    return math.exp(min(max(log_amplitude, math.log(value[0])), 0.0))


def decorrelation_time(ages: np.ndarray, g: np.ndarray) -> tuple[str, float | None, float | None]:
    """(status, τ, bound) from normalised correlations ``g`` at increasing ``ages`` (frames):
    τ where g first falls below 1/e, interpolated in ln(-ln g) against ln age (linearly in g
    where g >= 1 or <= 0 at a bracket end, the noise having pushed it out of (0, 1)); NaN ages
    are skipped. ``above`` with the oldest age, ``below`` with the youngest, ``warming_up`` if none."""
    age, value = _valid(ages, g)
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


def _valid(ages: np.ndarray, g: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ages (frames) and correlations where g is a number, the ages checked."""
    age = np.asarray(ages, np.float64)
    value = np.asarray(g, np.float64)
    if age.shape != value.shape or age.ndim != 1 or (age <= 0).any() or (np.diff(age) <= 0).any():
        raise EstimatorError("ages must be increasing positive frames, one per correlation")
    valid = np.isfinite(value)
    return age[valid], value[valid]


def _lit_level(noise: NoiseModel) -> float:
    """The level above μ_dark (DN) from which a local mean counts as lit: DARK_SNR noise σ at that
    level (signal_quality's bound), by bisection (level - DARK_SNR·σ(level) changes sign once)."""
    def short(level: float) -> bool:
        return level <= DARK_SNR * math.sqrt(float(noise.variance(level + noise.dark_mean)))

    low, high = 0.0, 1.0
    while short(high):
        low, high = high, 2.0 * high
    for _ in range(60):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if short(middle) else (low, middle)
    return max(high, float(np.finfo(np.float32).tiny))  # > 0: a noise-free model lights any level > 0


class _Layout:
    """Where a region's pixels and their local means are read from a frame: the region's bounding
    box, the frame's pixels around it that its boxes reach, and each box's pixel count (boxes cut
    at the frame's edge average what they cover)."""

    def __init__(self, region: np.ndarray, side: int) -> None:
        height, width = region.shape
        rows, cols = np.flatnonzero(region.any(axis=1)), np.flatnonzero(region.any(axis=0))
        self.rows = slice(int(rows[0]), int(rows[-1]) + 1)
        self.cols = slice(int(cols[0]), int(cols[-1]) + 1)
        self.inner = region[self.rows, self.cols]
        self.full = bool(self.inner.all())  # a rectangle: its pixels are a view, no gather
        self.pixels = int(self.inner.sum())
        half = side // 2
        self.outer_rows = slice(max(self.rows.start - half, 0), min(self.rows.stop + half, height))
        self.outer_cols = slice(max(self.cols.start - half, 0), min(self.cols.stop + half, width))

        def edges(inside: slice, outside: slice) -> tuple[np.ndarray, np.ndarray]:
            at = np.arange(inside.start, inside.stop)
            low = np.clip(at - half, outside.start, outside.stop) - outside.start
            return low, np.clip(at + half + 1, outside.start, outside.stop) - outside.start

        self.row_low, self.row_high = edges(self.rows, self.outer_rows)
        self.col_low, self.col_high = edges(self.cols, self.outer_cols)
        count = np.outer(self.row_high - self.row_low, self.col_high - self.col_low).astype(np.float64)
        self.inverse_count = 1.0 / count
        # Var(n_p/M_p) ≈ σ_p²/M_p²·(1 - 1/B): the pixel's own noise is 1/B of its box mean's
        self.shrink = (1.0 - 1.0 / self.pick(count)) if side else 1.0 - 1.0 / self.pixels

    def pick(self, box: np.ndarray) -> np.ndarray:
        """The region's pixels of a bounding-box array, flat."""
        return box.reshape(-1) if self.full else box[self.inner]

    def outer(self, image: np.ndarray) -> np.ndarray:
        return image[self.outer_rows, self.outer_cols]

    def values(self, image: np.ndarray) -> np.ndarray:
        return self.pick(image[self.rows, self.cols])

    def local_means(self, image: np.ndarray) -> np.ndarray:
        """Each region pixel's box mean (DN, float64), by cumulative sums along each axis (exact
        integer sums for integer frames)."""
        outer = self.outer(image)
        kind = np.int64 if np.issubdtype(outer.dtype, np.integer) else np.float64
        down = np.zeros((outer.shape[0] + 1, outer.shape[1]), kind)
        np.cumsum(outer, axis=0, dtype=kind, out=down[1:])
        band = down[self.row_high] - down[self.row_low]
        across = np.zeros((band.shape[0], band.shape[1] + 1), kind)
        np.cumsum(band, axis=1, out=across[:, 1:])
        total = across[:, self.col_high] - across[:, self.col_low]
        return self.pick(total * self.inverse_count)
