"""Each region's drying kinetics in seconds (issue 37; docs/kinetics.md, "In the daemon and the
timeline"): one :class:`~edgedsm.estimators.kinetics.Kinetics` per region fed with every frame,
read when a value is wanted, its decorrelation time τ·Δt in s and its rate 1/(τ·Δt) in Hz, or the
status that says why there is none. The daemon's pipeline thread, ``analyze --timeline --kinetics`` and the
measurement core read it through :class:`KineticsRegions`: the same numbers for the same frames.

Where the work runs: :meth:`KineticsRegions.push` is O(region pixels) per frame (the fused numba
pass; ``step`` divides it by step²); :meth:`KineticsRegions.read` is O(slots × region pixels) and is
called at the evaluation cadence, not every frame (their cost against the default push:
docs/kinetics.md, "Cost in the daemon at 2048²"). Both touch the reference frames,
so both run on the thread that pushes (the daemon's pipeline thread): the evaluator gets the
readings, never the frames.

The frame interval Δt: the ages are counted in pushes; the longest age in frames is fixed when the
first interval is known (``[kinetics] longest_age_s``/Δt), the readings are put in seconds with the
interval at each read. The camera's noise model is the datasheet's (``[camera.noise]``); without
one the shot noise stays in the zero lag and τ reads short by the noise's share of the speckle
variance (docs/kinetics.md: 1-3 % on the glue series), the dark level is taken as 0.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from edgedsm.config.kinetics import KineticsSection
from edgedsm.errors import EstimatorError
from edgedsm.estimators import noise as noise_models
from edgedsm.estimators.kinetics import ABOVE, BELOW, OK, WARMING_UP, Kinetics
from edgedsm.estimators.noise import NoiseModel
from edgedsm.messages import RegionKinetics

#: Statuses whose bound is judged as the value (τ is at least / at most it): judged as τc is.
BOUNDED = (ABOVE, BELOW)


def judged_seconds(reading: RegionKinetics | None) -> float | None:
    """What a region's thresholds judge from its kinetics: τ in s, the bound (s) when τ is above
    the longest age or below a frame (as τc's bounds are judged), None otherwise (no light to
    time: dark, saturated, not speckle; warming up): the state is held."""
    if reading is None:
        return None
    if reading.status == OK:
        return reading.tau_s
    return reading.bound_s if reading.status in BOUNDED else None


def reading_of(status: str, tau: float | None, bound: float | None, interval_s: float, frame: int) -> RegionKinetics:
    """A measure in frames put in seconds: τ·Δt (s), its rate 1/(τ·Δt) (Hz), the bound·Δt."""
    tau_s = None if tau is None else tau * interval_s
    return RegionKinetics(status=status, tau_s=tau_s, rate_hz=None if tau_s is None else 1.0 / tau_s,
                          bound_s=None if bound is None else bound * interval_s, frame=frame)


class KineticsRegions:
    """Every region's :class:`Kinetics` (one thread: the one that pushes). ``masks``: boolean
    masks in the frames' shape; ``noise``: the camera's model (None: noise-free, dark level 0);
    ``top``: full scale in grey levels (None: the frames' dtype's)."""

    def __init__(self, section: KineticsSection, masks: Mapping[str, np.ndarray], noise: NoiseModel | None = None,
                 top: float | None = None) -> None:
        if not masks:
            raise EstimatorError("no region to follow")
        step = section.step_for(max(int(np.count_nonzero(mask)) for mask in masks.values()))
        self.step = step
        self.section = section
        self.masks = {name: np.ascontiguousarray(np.asarray(mask, bool)[::step, ::step])
                      for name, mask in masks.items()}
        for name, mask in self.masks.items():
            if not mask.any():
                raise EstimatorError(f"region {name!r} keeps no pixel at kinetics.step = {step}")
        self.noise = noise if noise is not None else noise_models.from_datasheet(0.0, 0.0)
        self.top = top
        self.regions: dict[str, Kinetics] = {}  # built at the first push with a known interval
        self.longest_frames: int | None = None
        self.pushed = 0

    @property
    def memory_bytes(self) -> int:
        """Bytes of kept pixels over every region (0 before the first push)."""
        return sum(kinetics.memory_bytes for kinetics in self.regions.values())

    @staticmethod
    def bytes_for(section: KineticsSection, masks: Mapping[str, np.ndarray], interval_s: float) -> int:
        """The reference frames' memory for ``masks`` at ``interval_s``: (slots + 1) × 4 bytes per
        kept pixel (the engine budget checks it before anything is allocated)."""
        step = section.step_for(max(int(np.count_nonzero(mask)) for mask in masks.values()))
        pixels = sum(int(np.count_nonzero(np.asarray(mask, bool)[::step, ::step])) for mask in masks.values())
        return (section.slots(interval_s) + 1) * 4 * pixels

    @property
    def built(self) -> bool:
        """The regions' reference frames exist (a frame came with a known interval)."""
        return bool(self.regions)

    def push(self, frame: np.ndarray, interval_s: float | None) -> None:
        """One frame (2-D, the masks' shape) into every region; ``interval_s``: the frame interval
        (s), needed until :attr:`built` (the longest age in frames is fixed then; before, a frame
        without one is skipped: the ages count from the first frame with a known interval)."""
        if not self.regions:
            if interval_s is None:
                return
            self.longest_frames = self.section.longest_age(interval_s)
            self.regions = {name: Kinetics(mask, self.noise, self.longest_frames, self.section.per_octave,
                                           top=self.top) for name, mask in self.masks.items()}
        step = self.step  # the section's, or the one chosen for these regions (step = None: auto)
        view = frame if step == 1 else frame[::step, ::step]
        for kinetics in self.regions.values():
            kinetics.push(view)
        self.pushed += 1

    def read(self, interval_s: float | None) -> dict[str, RegionKinetics]:
        """Each region's τ (s), rate (Hz) and status now (``warming_up`` before a frame or an
        interval); O(slots × region pixels): at the evaluation cadence."""
        if not self.regions or interval_s is None or not math.isfinite(interval_s) or interval_s <= 0:
            return {name: RegionKinetics(status=WARMING_UP) for name in self.masks}
        out = {}
        for name, kinetics in self.regions.items():
            result = kinetics.measure(white=self.section.white)
            out[name] = reading_of(result.status, result.tau, result.bound, interval_s, result.frame)
        return out

    def reset(self) -> None:
        """Forget every reference frame (a rebaseline, a restart of the measurement)."""
        self.regions = {}
        self.longest_frames = None
        self.pushed = 0


def warm_up(deep: bool = False) -> None:
    """Compile (or load) the kinetics' fused pass and run a measure on a small region (8-bit, or
    16-bit frames with ``deep``): its first call would otherwise stall the thread that pushes."""
    frame = np.random.default_rng(0).integers(1, 200, (16, 16)).astype(np.uint16 if deep else np.uint8)
    kinetics = Kinetics(np.ones(frame.shape, bool), noise_models.from_datasheet(0.0, 0.0), 4)
    for _ in range(3):
        kinetics.push(frame)
    kinetics.measure()


#: ``analyze --timeline --kinetics``' columns (after the others): τ (s), its rate (Hz), the
#: status, the bound (s) of ``above`` / ``below``.
COLUMNS = ("kinetics_tau_s", "kinetics_rate_hz", "kinetics_status", "kinetics_bound_s")


def cells(reading: RegionKinetics | None) -> tuple[float, float, str, float]:
    """A reading's :data:`COLUMNS` (NaN where it has no number; status "off" without one)."""
    if reading is None:
        return (math.nan, math.nan, "off", math.nan)
    return tuple(math.nan if value is None else value  # type: ignore[return-value]
                 for value in (reading.tau_s, reading.rate_hz, reading.status, reading.bound_s))
