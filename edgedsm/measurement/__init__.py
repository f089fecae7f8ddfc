"""The measurement core: the engine from the config (:mod:`~edgedsm.measurement.spec`), the signal
judge (:mod:`~edgedsm.measurement.judge`) and the object that turns frames or the engine's region
statistics into per-region values, noise floors, judged activity, signal quality and drying states
(:mod:`~edgedsm.measurement.core`). Below the daemon: the daemon, ``analyze`` and ``tune`` use it;
it imports the estimators, the config's sections and the state machine, never the daemon."""

from edgedsm.measurement.core import REGION_VIEW, Core, Evaluation, Judgement, RegionReading, judge_window, view_of
from edgedsm.measurement.spec import EngineSpec, engine_estimators

__all__ = ["REGION_VIEW", "Core", "EngineSpec", "Evaluation", "Judgement", "RegionReading", "engine_estimators",
           "judge_window", "view_of"]
