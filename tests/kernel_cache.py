"""Compile the daemon's kernels into numba's disk cache in a separate process, as a daemon's
start does (``edgedsm.daemon.engine_budget.warm_up``), and say which kernels that process did not find there."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

PROBE = r"""
import gc, json, sys
from numba.core.registry import CPUDispatcher
from edgedsm.config import DaemonConfig
from edgedsm.daemon.engine_budget import warm_up
from edgedsm.validation import validate
config = validate(DaemonConfig, json.loads(sys.argv[1]), "<warm start>")
shape = json.loads(sys.argv[2])
warm_up(config, None if shape is None else tuple(shape))
missed = sorted({obj.py_func.__qualname__ for obj in gc.get_objects()
                 if isinstance(obj, CPUDispatcher) and obj._cache.__class__.__name__ != "NullCache"
                 and obj.stats.cache_misses})
print(json.dumps(missed))
"""

#: Estimator settings whose kernels the integration tests' daemons use, and the size of their frames:
#: the default settings on any (the fake GigE camera's 512² frames run the parallel kernels), the
#: others on the simulated camera's 128² (drying_demo.toml; the serial kernels only).
ESTIMATORS = (({}, None), ({"mode": "tumbling", "tau_c": True}, (128, 128)), ({"tau_c": True}, (128, 128)),
              ({"mode": "exponential"}, (128, 128)))


def warm_start(estimator: dict, frame_shape: tuple[int, int] | None = None, timeout_s: float = 240.0) -> list[str]:
    """Run a daemon's warm-up for ``estimator`` settings and frames of ``frame_shape`` (None: any) in
    a new process; the kernels it compiled (qualified names) because numba's disk cache did not
    have them."""
    config = {"camera": {"uri": f"sim:{REPO / 'config' / 'scenes' / 'drying_demo.toml'}"},
              "estimator": {"window": 40, "lag": 3, **estimator}}
    done = subprocess.run([sys.executable, "-c", PROBE, json.dumps(config), json.dumps(frame_shape)],
                          capture_output=True, text=True, timeout=timeout_s, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"the warm-up failed: {done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])
