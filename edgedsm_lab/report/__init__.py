"""Reports built from simulations: the reproduction of the paper's §2 noise analysis."""

from edgedsm_lab.report.reproduce import ProgressBar, ProgressFactory, Settings, plan_runs, reproduce

__all__ = ["ProgressBar", "ProgressFactory", "Settings", "plan_runs", "reproduce"]
