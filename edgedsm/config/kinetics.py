"""``[kinetics]``: each region's decorrelation time over decades (docs/kinetics.md, issue 37).

Per region the daemon keeps past frames at ages spread evenly in log age up to ``longest_age_s``
and reads, at the states cadence, the age at which the region's normalised two-time correlation
falls to 1/e (:class:`edgedsm.estimators.kinetics.Kinetics`). Off by default: it costs memory
((slots + 1) × 4 bytes per kept pixel) and a push per frame of the order of the default S1+S2+S3
push at full resolution (docs/kinetics.md, "Cost in the daemon at 2048²"); ``step`` keeps every
step-th pixel each way and divides both by step².
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from pydantic import Field, model_validator

from edgedsm.config.regions import RegionSettings
from edgedsm.estimators.kinetics import DEFAULT_PER_OCTAVE, MAX_LONGEST_AGE, slot_schedule
from edgedsm.validation import StrictModel

#: The longest age a config may ask for: 30 days.
MAX_LONGEST_AGE_S = 30 * 86_400.0
#: Coarsest subsampling: every 16th pixel each way (a 2048² frame keeps 128²).
MAX_STEP = 16
#: The default step keeps a region at most this many pixels: enough speckles for τ within a few % (a
#: 48² film reads it within 7 %), at a cost within 10 % of the default push at 2048² (docs/kinetics.md).
AUTO_PIXELS = 16_384
#: Refs per octave a config may ask for (the estimator takes up to 64; beyond 16 the slots cost
#: memory without telling τ apart better than its frame-by-frame scatter).
MAX_PER_OCTAVE = 16


#: Drying stages a config may name (ASTM D5895's set-to-touch, tack-free, dry-hard, dry-through...).
MAX_STAGES = 8


class StageSection(StrictModel):
    """A drying stage of the plant's own: reached when a region's speckle rate 1/τ falls to
    ``rate_below_hz`` and stays there ``[kinetics] stage_dwell_s``."""

    name: str = Field(min_length=1, max_length=32, pattern=r"^[A-Za-z0-9_.-]+$",
                      description="the stage's name in alerts and stats, e.g. set_to_touch, tack_free, dry_hard")
    rate_below_hz: float = Field(gt=0, le=1e6, description="the speckle rate 1/τ in Hz at or below which the "
                                                           "stage is reached (τ at or above 1/rate_below_hz s)")


class KineticsSection(StrictModel):
    """``[kinetics]``: the per-region decorrelation time τ(t) in s and its rate 1/τ in Hz."""

    enabled: bool = Field(False, description="measure each region's decorrelation time over decades "
                                             "(docs/kinetics.md); off by default: at 2048² a push of two regions "
                                             "covering the frame costs 2-7x the default S1+S2+S3 push at full "
                                             "resolution (step = 1), 0.5x at step = 4, 0.06x at step = 12")
    per_octave: int = Field(DEFAULT_PER_OCTAVE, ge=1, le=MAX_PER_OCTAVE,
                            description="reference frames per octave of age (4: 57 kept frames up to 4,096 frames, "
                                        "each age within 19 % of its nominal one)")
    longest_age_s: float = Field(3600.0, gt=0, le=MAX_LONGEST_AGE_S,
                                 description="the oldest reference frame in seconds: τ longer than this reads "
                                             "'above' it (memory: 4 bytes per kept pixel per age kept)")
    step: int | None = Field(None, ge=1, le=MAX_STEP,
                             description="keep every step-th pixel each way of each region (frame[::step, ::step]): "
                                         "memory and cost fall by step²; pixels further apart than a speckle keep "
                                         "the measure (docs/kinetics.md: 1.02 τ/τc at step 4); default: the "
                                         f"smallest step that keeps the largest region at most {AUTO_PIXELS:,} "
                                         "pixels (a region of 128² or less: every pixel; two regions covering a "
                                         "2048² frame: step 12, about 0.06x the default push)")
    stages: list[StageSection] = Field(default_factory=list, max_length=MAX_STAGES,
                                       description="drying stages in the order they are reached, each at a "
                                                   "lower rate: per region the time each is reached (an alert, "
                                                   "the stats) and the time to the next from the rate's trend")
    stage_dwell_s: float = Field(10.0, ge=0, le=86_400, description="the rate must stay at or below a stage's "
                                                                    "threshold this long for it to be reached "
                                                                    "(τ scatters about 10 % frame to frame)")
    trend_window_s: float = Field(300.0, gt=0, le=30 * 86_400.0,
                                  description="the rate's trend (a line through ln rate against time) over this "
                                              "window gives the time to the next stage")
    white: bool = Field(False, description="take a white step (phase noise, vibration: outdoor or vibrating "
                                           "set-ups) out of the correlation before reading τ; off: a stretched "
                                           "decay would be read long (docs/kinetics.md)")

    @model_validator(mode="after")
    def _stages_in_order(self) -> KineticsSection:
        names = [stage.name for stage in self.stages]
        if len(set(names)) != len(names):
            raise ValueError(f"stages: names must be unique, got {names}")
        for index, (earlier, later) in enumerate(zip(self.stages, self.stages[1:], strict=False), start=1):
            if later.rate_below_hz >= earlier.rate_below_hz:
                raise ValueError(f"stages.{index}.rate_below_hz: {later.rate_below_hz:g} Hz is not below the "
                                 f"stage before's {earlier.rate_below_hz:g} Hz (a film's rate falls as it dries)")
        oldest = self.longest_age_s / 2.0 ** (1.0 / self.per_octave)
        for index, stage in enumerate(self.stages):
            if 1.0 / stage.rate_below_hz >= oldest:
                raise ValueError(f"stages.{index}.rate_below_hz: τ = 1/{stage.rate_below_hz:g} Hz = "
                                 f"{1.0 / stage.rate_below_hz:.4g} s is not below the oldest reference's age, "
                                 f"longest_age_s / 2^(1/per_octave) = {oldest:.4g} s: never reached")
        return self

    def step_for(self, region_pixels: int) -> int:
        """The step each way for regions whose largest has ``region_pixels`` pixels: ``step``, or
        the smallest that keeps it at most ``AUTO_PIXELS`` (at most ``MAX_STEP``)."""
        if self.step is not None:
            return self.step
        return min(max(1, math.ceil(math.sqrt(region_pixels / AUTO_PIXELS) - 1e-12)), MAX_STEP)

    def longest_age(self, interval_s: float) -> int:
        """The longest age in frames at frame interval ``interval_s`` (s): ceil(longest_age_s/Δt),
        at least 2 (one reference beside the previous frame)."""
        if not (math.isfinite(interval_s) and interval_s > 0):
            raise ValueError(f"frame interval must be a positive number of seconds, got {interval_s!r}")
        return int(min(max(math.ceil(self.longest_age_s / interval_s - 1e-9), 2), MAX_LONGEST_AGE))

    def slots(self, interval_s: float) -> int:
        """Reference frames kept per region at ``interval_s`` (memory: slots + 1 buffers)."""
        return int(slot_schedule(self.longest_age(interval_s), self.per_octave)[0].size)


def kinetics_problem(section: KineticsSection, activity: str, regions: Sequence[RegionSettings]) -> str | None:
    """What is wrong with judging on the kinetics (``estimator.activity = 'kinetics'``) or with
    ``[kinetics]`` beside the regions, with the key path; None when nothing is."""
    if activity != "kinetics":
        return None
    if not section.enabled:
        return ("estimator.activity: 'kinetics' judges each region on its decorrelation time: it needs "
                "[kinetics] enabled = true (off by default: it costs memory and a push per frame)")
    for index, region in enumerate(regions):
        if region.wet_below_s is None or region.dry_above_s is None:
            return (f"regions.{index}.wet_above: estimator.activity = 'kinetics' judges every region on its "
                    "decorrelation time in seconds: give wet_below_s and dry_above_s")
        # the oldest reference's age cycles within a factor 2^(1/per_octave) below the longest age
        oldest = section.longest_age_s / 2.0 ** (1.0 / section.per_octave)
        if region.dry_above_s * (1.0 + region.hysteresis) >= oldest:
            return (f"regions.{index}.dry_above_s: {region.dry_above_s:g} s (with its hysteresis "
                    f"{region.hysteresis:g}) is not below the oldest reference's age, kinetics.longest_age_s / "
                    f"2^(1/per_octave) = {oldest:.4g} s: τ is measured up to it only, the region could "
                    "never read dry")
    return None
