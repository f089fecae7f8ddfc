"""``[estimator]``: what the engine computes, over which window and lag (the paper's N and m)."""

from __future__ import annotations

import os
from typing import Literal

from pydantic import Field, ValidationInfo, field_validator, model_validator
from pydantic_core import PydanticCustomError

from edgedsm.estimators import registry
from edgedsm.estimators.correlation_time import default_max_lag, max_lag_problem, tau_mode_problem
from edgedsm.validation import StrictModel

#: The paper's maps, which the daemon always forms, publishes and reduces per region (the registry's).
PAPER_MAPS: tuple[str, ...] = registry.paper_maps()


def descriptor_activities() -> tuple[str, ...]:
    """The field's descriptors the daemon can judge on (docs/descriptors.md): the registry's
    activities formed as a map of their own beside S1-S3 when the activity is one of them (not τc,
    which is fitted, nor kinetics, a region-level measure of its own: ``[kinetics]``; each costs a
    little per push: docs/descriptors.md)."""
    return tuple(r.name for r in registry.records(activity=True, paper=False) if r.source != "tau" and r.streams)


#: :func:`descriptor_activities` of the records registered at import (for importers of a constant).
DESCRIPTOR_ACTIVITIES: tuple[str, ...] = descriptor_activities()


class EstimatorSection(StrictModel):
    activity: str = Field(
        "s2", json_schema_extra={"enum": list(registry.activities())},
        description="estimator the drying states are judged on, one of the registry's activities "
                    "(edgedsm.estimators.registry; S3 saturates once τc >> N; tau_c: the "
                    "region's correlation time in seconds, thresholds wet_below_s / dry_above_s; the "
                    "field's descriptors: contrast = temporal σ/⟨I⟩, fujii = 200·S2 at q = 0 (the engine "
                    "then runs at q = 0: an explicit non-zero q is refused), im = mean (I_k - I_{k+m})² in "
                    "grey levels²; gd = generalized differences Σ_{i<j} |I_i - I_j| / C(N,2) in grey levels, "
                    "mode 'sliding' or 'tumbling', O(N) a pixel: a push of S1+S2+S3+gd 10-12x one of S1+S2+S3 at "
                    "N = 64 sliding, ~6x tumbling; band_ratio = high-band / (low-band power + q) of each pixel's "
                    "periodogram, split at band_split_hz, mode 'sliding' or 'tumbling', 16 bytes per pixel per "
                    "DFT bin of the smaller band; docs/descriptors.md; kinetics = each region's decorrelation "
                    "time in s over decades, thresholds wet_below_s / dry_above_s, needs [kinetics] enabled: "
                    "docs/kinetics.md)")
    window: int = Field(200, ge=2, le=100_000, description="N: frames per map (paper: 200)")
    lag: int = Field(10, ge=1, le=99_999, description="m: time lag in frames (paper: 10)")
    q: float = Field(1.0, ge=0, le=1e9, description="S2 regulariser q in grey levels (avoids 0/0)")
    mode: Literal["sliding", "exponential", "tumbling"] = Field("sliding", description="window mode of the engine")
    tau_c: bool = Field(
        False, description="also estimate the correlation time τc (docs/tau_c.md): a push of S1+S2+S3+τc "
                           "costs about 1.6-2.0x one of S1+S2+S3 at 2048², so off unless asked for here or "
                           "needed (activity = 'tau_c', or a region with wet_below_s / dry_above_s); needs mode "
                           "'sliding' or 'tumbling'")
    max_lag: int | None = Field(None, ge=1, le=99_998,
                                description="K: the longest lag in frames that τc is fitted over, at multi-tau lags "
                                            "1, 2, 3, 4, 6, 8, … K (default window/2); τc is measured up "
                                            "to K·Δt, above it reported as '> K·Δt'")
    band_split_hz: float | None = Field(
        None, gt=0, le=1e6, description="activity = 'band_ratio': the frequency in Hz between the low band (0, F] "
                                        "and the high band (F, Nyquist] (needs camera.frame_interval_s; below the "
                                        "Nyquist frequency 1/(2Δt)); default half the Nyquist frequency")
    tau_c_map: bool = Field(True, description="publish the τc map (seconds) with the other maps")
    tau_c_map_block: int | None = Field(
        None, ge=1, le=256, description="side b of the b×b pixel blocks the τc map is fitted over, pooled as a "
                                        "region (1: per pixel, ~6 µs each on the evaluator thread per map); "
                                        "default: the smallest b that keeps the map at 65,536 fits (2048²: 8)")
    ambient_correction: bool = Field(
        False, description="subtract the measured dark level from every frame before all estimators (off: the "
                           "validation in docs/ambient.md shows it distorts S2; use S3 under ambient light)")
    threads: int | None = Field(None, ge=1, le=256, description="kernel threads (default: all cores)")
    noise_floor: bool = Field(
        True, description="judge the drying states on the activity above the camera's noise floor (docs/noise.md): "
                          "a darkening or dimmer film does not read wet again; a region whose light is dark, "
                          "saturated or not speckle keeps its state and raises a warning")
    noise_patch: int = Field(64, ge=16, le=256,
                             description="side in pixels of the patch at each region's centre whose last N frames "
                                         "give its noise floor and signal quality (cost: ~0.1 s per region per "
                                         "stats interval at 64, on the evaluator thread)")
    intensity_change: float = Field(
        3.0, gt=1.0, le=1000.0, description="a region's mean intensity changing by more than this factor from its "
                                            "value when the window first filled raises a warning (exposure, laser "
                                            "power, reflectance or ambient light changed)")
    area: Literal["frame", "regions"] = Field(
        "frame", description="frame: maps of the whole sensor; regions: only the bounding box of all regions "
                             "(the cost follows the regions; the published maps cover that box)")

    @field_validator("activity")
    @classmethod
    def _known_activity(cls, activity: str) -> str:
        if activity not in (known := registry.activities()):
            # worded as pydantic words a Literal's refusal (the choices are the registry's, read now)
            expected = ", ".join(repr(name) for name in known[:-1]) + f" or {known[-1]!r}"
            raise PydanticCustomError("literal_error", "Input should be {expected}", {"expected": expected})
        return activity

    @model_validator(mode="after")
    def _lag_fits(self) -> EstimatorSection:
        if self.lag >= self.window:
            raise ValueError(f"lag ({self.lag}) must be smaller than window ({self.window})")
        cores = os.cpu_count() or 1
        if self.threads is not None and self.threads > cores:
            raise ValueError(f"threads ({self.threads}) is more than this machine's {cores} cores")
        if self.max_lag is not None and (problem := max_lag_problem(self.max_lag, self.window)):
            raise ValueError(problem)
        if problem := registry.mode_problem(self.activity, self.mode):
            raise ValueError(f"activity: {problem}")
        if self.tau_c and (problem := tau_mode_problem(self.mode)):
            raise ValueError(f"tau_c: {problem}")
        return self

    @field_validator("q")
    @classmethod
    def _q_zero_maps_have_no_q(cls, q: float, info: ValidationInfo) -> float:
        # a q given explicitly (the default is not validated) beside an activity formed at q = 0 (Fujii)
        activity = info.data.get("activity")
        if activity is not None and registry.get(activity).needs_q_zero and q != 0:
            record = registry.get(activity)
            raise ValueError(f"q = {q} with estimator.activity = {activity!r}: {record.label} is {record.summary} "
                             f"(BSLTL's {record.bsltl}.m), so the engine runs at q = 0; remove estimator.q or set "
                             "it to 0")
        return q

    @property
    def engine_q(self) -> float:
        """The q the engine runs at: 0 when judged on a map formed at q = 0 (Fujii: 200·S2 at q = 0), else ``q``."""
        return registry.get(self.activity).q_for(self.q)

    @property
    def maps(self) -> tuple[str, ...]:
        """The maps the daemon forms, publishes and reduces per region: S1, S2, S3 and the activity
        when it is one of the field's descriptors."""
        paper = registry.paper_maps()
        return (*paper, self.activity) if self.activity in descriptor_activities() else paper

    @property
    def lags(self) -> int:
        """K, the τc lags in frames (``max_lag`` or its default)."""
        return self.max_lag if self.max_lag is not None else default_max_lag(self.window)
