"""Re-export of :mod:`edgedsm.estimators.masked_moments` (the region-statistics pass moved down
into the estimators, which use it; :mod:`edgedsm.analysis` still imports it from here)."""

from edgedsm.estimators.masked_moments import _moments, _moments_numpy, _moments_source, masked_moments

__all__ = ["_moments", "_moments_numpy", "_moments_source", "masked_moments"]
