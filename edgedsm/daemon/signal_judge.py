"""The signal judge moved to the measurement core (:mod:`edgedsm.measurement.judge`); this name
stays for the daemon's modules that import it."""

from edgedsm.measurement import judge as _judge

FLOOR_KEPT, HOLD, REFRESH_EVERY = _judge.FLOOR_KEPT, _judge.HOLD, _judge.REFRESH_EVERY
ModelKeeper, SignalJudge, SignalWarning = _judge.ModelKeeper, _judge.SignalJudge, _judge.SignalWarning
change_reason, hold_reason, warm_up = _judge.change_reason, _judge.hold_reason, _judge.warm_up
