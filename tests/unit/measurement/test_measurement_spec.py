"""The engine from the config, once (edgedsm.measurement.EngineSpec): what the daemon, its memory
estimate, analyze and tune build is the config's engine, bands and τc included."""

from __future__ import annotations

import numpy as np

from edgedsm.config import DaemonConfig
from edgedsm.daemon.engine_budget import make_engine
from edgedsm.measurement import EngineSpec
from edgedsm.validation import validate


def _config(estimator: dict, region: dict | None = None, camera: dict | None = None) -> DaemonConfig:
    regions = [{"name": "a", "wet_above": 0.3, "dry_below": 0.1, **(region or {})}]
    return validate(DaemonConfig, {"camera": {"uri": "sim:default", **(camera or {})}, "estimator": estimator,
                                   "regions": regions}, "<spec>")


def test_the_spec_is_the_configs_engine_with_tau_c_when_a_region_needs_it():
    plain = EngineSpec.of(_config({"window": 40, "lag": 3, "q": 2.0}))
    assert (plain.window, plain.lag, plain.q, plain.mode) == (40, 3, 2.0, "sliding")
    assert plain.estimators == ("s1", "s2", "s3") and plain.max_lag is None and not plain.tau_c
    # a region judged on τc switches τc on, at the config's K (default N/2)
    tau = EngineSpec.of(_config({"window": 40, "lag": 3}, {"wet_above": None, "dry_below": None,
                                                           "wet_below_s": 0.5, "dry_above_s": 5.0}))
    assert tau.estimators == ("s1", "s2", "s3", "tau_c") and tau.max_lag == 20
    # Fujii runs its engine at q = 0 (200·S2 at q = 0) and is formed beside S1-S3
    fujii = EngineSpec.of(_config({"window": 40, "lag": 3, "activity": "fujii"}))
    assert fujii.q == 0.0 and fujii.estimators == ("s1", "s2", "s3", "fujii")
    # the band ratio's split and the camera's frame interval reach the engine
    bands = EngineSpec.of(_config({"window": 40, "lag": 3, "activity": "band_ratio", "band_split_hz": 2.0},
                                  camera={"frame_interval_s": 0.05}))
    assert (bands.dt, bands.band_split) == (0.05, 2.0) and bands.estimators[-1] == "band_ratio"


def test_the_daemons_engine_is_the_specs_and_replaced_drops_k_without_tau_c():
    config = _config({"window": 30, "lag": 2, "tau_c": True, "max_lag": 8})
    engine = make_engine(config, (8, 12), 8, threads=1)
    spec = EngineSpec.of(config)
    assert (engine.window, engine.lag, engine.shape) == (spec.window, spec.lag, (8, 12))
    assert tuple(engine.estimators) == spec.estimators and spec.max_lag == 8
    frames = np.random.default_rng(1).integers(0, 255, (31, 8, 12), dtype=np.uint8)
    mine = spec.engine((8, 12), 8, threads=1)
    for frame in frames:
        engine.push(frame)
        mine.push(frame)
    np.testing.assert_array_equal(engine.maps(("s2",))["s2"], mine.maps(("s2",))["s2"])
    shorter = spec.replaced(window=60, estimators=spec.maps)
    assert shorter.window == 60 and shorter.max_lag is None and not shorter.tau_c
