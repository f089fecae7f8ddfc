"""Reports built from simulations: the reproduction of the paper's §2 noise analysis."""

from edgedsm.report.reproduce import Settings, reproduce

__all__ = ["Settings", "reproduce"]
