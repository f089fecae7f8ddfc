"""The lab beside the house: benchmarks that print tables (``edgedsm bench``) and the paper's
§2 reproduction (``edgedsm reproduce``). They use edgedsm's public parts (the simulator, the
estimators, the daemon's Pipeline through its probes) and nothing imports them but the two
commands, which load them by name when asked."""
