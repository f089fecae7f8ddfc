"""A region's drying thresholds as one validated value (:class:`Thresholds`): what
``[[regions]]`` says (:mod:`edgedsm.config.regions` builds it, and so refuses bad thresholds when
the file is read) and what the drying-state machine (:mod:`edgedsm.drying`) judges with. Plain
data and its checks, no judging: the machine, its hysteresis and dwell live in drying.py.

Units: the thresholds are in the chosen estimator's unit (S1 grey levels, S2/S3 dimensionless),
or, judged on τc (:meth:`Thresholds.of_tau`), rates 1/τc in 1/s; times in seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class Thresholds:
    """Activity thresholds of one region (units of the chosen estimator), times in seconds."""

    wet_above: float
    dry_below: float
    hysteresis: float = 0.05
    min_dwell_s: float = 5.0
    trend_window_s: float = 120.0
    #: the observed values are correlation times τc in s (large = dry); the thresholds above are
    #: then rates 1/τc (1/s). Build such thresholds with :meth:`of_tau`.
    on_tau: bool = False

    def __post_init__(self) -> None:
        if not (0 < self.dry_below < self.wet_above and math.isfinite(self.wet_above)):
            if self.on_tau:
                raise ValueError(f"need 0 < wet_below_s ({1 / self.wet_above:.6g}) < dry_above_s "
                                 f"({1 / self.dry_below:.6g})")
            raise ValueError(f"need 0 < dry_below ({self.dry_below}) < wet_above ({self.wet_above})")
        if not 0 <= self.hysteresis < 0.5:
            raise ValueError(f"hysteresis must be in [0, 0.5), got {self.hysteresis}")
        if self.dry_below * (1 + self.hysteresis) >= self.wet_above * (1 - self.hysteresis):
            names = "wet_below_s and dry_above_s" if self.on_tau else "dry_below and wet_above"
            raise ValueError(f"the hysteresis bands of {names} overlap")
        if self.min_dwell_s < 0 or self.trend_window_s <= 0:
            raise ValueError("min_dwell_s must be >= 0 and trend_window_s > 0")

    @classmethod
    def of_tau(cls, wet_below_s: float, dry_above_s: float, hysteresis: float = 0.05, min_dwell_s: float = 5.0,
               trend_window_s: float = 120.0) -> Thresholds:
        """Thresholds on τc in seconds: wet at τc <= ``wet_below_s``, dry at τc >= ``dry_above_s``."""
        if not (0 < wet_below_s < dry_above_s and math.isfinite(dry_above_s)):
            raise ValueError(f"need 0 < wet_below_s ({wet_below_s}) < dry_above_s ({dry_above_s})")
        return cls(1.0 / wet_below_s, 1.0 / dry_above_s, hysteresis, min_dwell_s, trend_window_s, on_tau=True)

    def activity_of(self, value: float | None) -> float | None:
        """The activity judged for an observed ``value``: the value itself, or 1/τc (None for τc <= 0,
        a region without signal)."""
        if value is None or not self.on_tau:
            return value
        return 1.0 / value if value > 0 else None
