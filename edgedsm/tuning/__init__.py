"""Commissioning from a reference run (``edgedsm tune``, docs/commissioning.md): every candidate
estimator, window and lag scored on a wet-to-dry run, thresholds proposed, the choice explained."""
