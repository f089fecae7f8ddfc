"""Activity estimators S1, S2, S3 (paper Eq. 1-4): batch references and streaming engine."""

from edgedsm.estimators.batch import all_maps, s1, s2, s3, temporal_sigma
from edgedsm.estimators.streaming import SlidingWindow

ESTIMATORS = ("s1", "s2", "s3")

__all__ = ["ESTIMATORS", "SlidingWindow", "all_maps", "s1", "s2", "s3", "temporal_sigma"]
