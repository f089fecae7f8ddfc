"""The daemon: the only place that wires devices, estimators, analysis and publishing."""
