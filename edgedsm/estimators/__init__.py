"""Activity estimators S1, S2, S3 (paper Eq. 1-4) and the correlation time τc: batch references and
streaming engine."""

from edgedsm.estimators.batch import all_maps, s1, s2, s3, temporal_sigma
from edgedsm.estimators.correlation_time import TauC, tau_c, tau_c_bounds
from edgedsm.estimators.streaming import SlidingWindow

ESTIMATORS = ("s1", "s2", "s3")

__all__ = ["ESTIMATORS", "SlidingWindow", "TauC", "all_maps", "s1", "s2", "s3", "tau_c", "tau_c_bounds",
           "temporal_sigma"]
