"""``[[regions]]``: a shape of :mod:`edgedsm.geometry` in camera pixels, a name and drying
thresholds (on the activity, or on τc in seconds)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
from pydantic import Discriminator, Field, Tag, model_validator

from edgedsm import geometry
from edgedsm.config.thresholds import Thresholds
from edgedsm.errors import ConfigError
from edgedsm.validation import StrictModel


class RegionSettings(StrictModel):
    """What a daemon region adds to its shape (``edgedsm.geometry``): a name and drying thresholds.
    Shapes are in camera pixels; a mask's path is relative to the config file."""

    name: str = Field(min_length=1, max_length=64, pattern=r"^[A-Za-z0-9_.-]+$", description="region name in MQTT")
    wet_above: float | None = Field(None, gt=0, le=1e9, description="activity (estimator.activity's region mean) "
                                                                    "at or above which the surface is wet")
    dry_below: float | None = Field(None, gt=0, le=1e9, description="activity at or below which the surface is dry")
    wet_below_s: float | None = Field(None, gt=0, le=86400,
                                      description="judge on τc instead: the region's correlation time (s) at or "
                                                  "below which the surface is wet (wet decorrelates fast)")
    dry_above_s: float | None = Field(None, gt=0, le=86400,
                                      description="judge on τc: the correlation time (s) at or above which the "
                                                  "surface is dry")
    hysteresis: float = Field(0.05, ge=0, lt=0.5, description="relative margin to leave a state")
    min_dwell_s: float = Field(10.0, ge=0, le=86400, description="a new state must hold this long")
    trend_window_s: float = Field(120.0, gt=0, le=86400, description="time-to-dry trend window")

    @model_validator(mode="after")
    def _thresholds_fit(self) -> RegionSettings:
        on_activity = (self.wet_above, self.dry_below)
        on_tau = (self.wet_below_s, self.dry_above_s)
        if any(v is not None for v in on_activity) and any(v is not None for v in on_tau):
            raise ValueError("give either wet_above/dry_below (activity) or wet_below_s/dry_above_s (τc in "
                             "seconds), not both")
        for pair, names in ((on_activity, "wet_above and dry_below"), (on_tau, "wet_below_s and dry_above_s")):
            if (pair[0] is None) != (pair[1] is None):
                raise ValueError(f"give both {names}")
        if all(v is None for v in (*on_activity, *on_tau)):
            raise ValueError("drying thresholds missing: give wet_above and dry_below (activity), or "
                             "wet_below_s and dry_above_s (τc in seconds)")
        self.thresholds()  # its ValueError names the problem
        return self

    @property
    def on_tau(self) -> bool:
        """Judged on the region's τc in seconds (wet_below_s / dry_above_s)."""
        return self.wet_below_s is not None

    def thresholds(self) -> Thresholds:
        if self.wet_below_s is not None and self.dry_above_s is not None:
            return Thresholds.of_tau(self.wet_below_s, self.dry_above_s, self.hysteresis, self.min_dwell_s,
                                     self.trend_window_s)
        assert self.wet_above is not None and self.dry_below is not None  # the validator checked
        return Thresholds(self.wet_above, self.dry_below, self.hysteresis, self.min_dwell_s, self.trend_window_s)

    def mask(self, shape: tuple[int, int], base_dir: Path) -> np.ndarray:
        """Boolean mask of the region on a frame of ``shape``; an empty region is a ConfigError."""
        mask = self.draw(shape, 1.0, base_dir)  # type: ignore[attr-defined]  # from the shape base
        if not mask.any():
            raise ConfigError(f"regions.{self.name}: the region has no pixel inside the {shape[1]}x{shape[0]} frame")
        return mask


class FullArea(geometry.Full, RegionSettings):
    pass


class RectArea(geometry.Rect, RegionSettings):
    pass


class CircleArea(geometry.Circle, RegionSettings):
    pass


class RingArea(geometry.Ring, RegionSettings):
    pass


class PolygonArea(geometry.Polygon, RegionSettings):
    pass


class TextArea(geometry.Text, RegionSettings):
    pass


class MaskArea(geometry.Mask, RegionSettings):
    pass


def _default_shape(value: object) -> object:
    # `shape` may be left out of a daemon region: the whole frame
    if isinstance(value, dict) and "shape" not in value:
        return {"shape": "full", **value}
    return value


def _shape_of(value: object) -> object:
    if isinstance(value, dict):
        return value.get("shape", "full")
    return getattr(value, "shape", None)


#: A daemon ``[[regions]]`` entry: one of the shapes of ``edgedsm.geometry`` plus RegionSettings.
RegionSection = Annotated[
    Annotated[FullArea, Tag("full")] | Annotated[RectArea, Tag("rect")] | Annotated[CircleArea, Tag("circle")]
    | Annotated[RingArea, Tag("ring")] | Annotated[PolygonArea, Tag("polygon")]
    | Annotated[TextArea, Tag("text")] | Annotated[MaskArea, Tag("mask")],
    Discriminator(_shape_of, custom_error_type="shape", custom_error_message=(
        f"shape must be one of {', '.join(geometry.SHAPE_NAMES)}")),
]


def _default_regions() -> list[RegionSection]:
    return [FullArea(name="full", wet_above=0.9, dry_below=0.5)]
