"""The engine from the config, once: :class:`EngineSpec` is every setting the streaming engine is
built with (window N, lag m, q, mode, the maps it keeps sums for, τc's longest lag K, the
bands' frame interval and split), read from the config's sections by :meth:`EngineSpec.of`.

The daemon's engine (``daemon/measurement.py``), its memory estimate and warm-up
(``daemon/engine_budget.py``), ``analyze --timeline`` and ``tune`` (one spec per window setting:
:meth:`EngineSpec.replaced`) all build their engines through :meth:`EngineSpec.engine`, so the
engine a memory budget was checked for, a timeline was drawn with and a candidate was scored on
is the one the daemon runs.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

from edgedsm.config import DaemonConfig
from edgedsm.config.estimator import EstimatorSection
from edgedsm.estimators import SlidingWindow


def engine_estimators(estimator: EstimatorSection, tau_c: bool) -> tuple[str, ...]:
    """What the engine keeps sums for: the maps the daemon forms (S1, S2, S3 and the activity when
    it is one of the field's descriptors: ``estimator.maps``), and τc when ``tau_c``."""
    maps = estimator.maps
    return (*maps, "tau_c") if tau_c else maps


@dataclass(frozen=True)
class EngineSpec:
    """The settings of one streaming engine (units: frames, grey levels for q, seconds for dt and
    Hz for band_split when dt is given)."""

    window: int
    lag: int
    q: float
    mode: str
    estimators: tuple[str, ...]
    max_lag: int | None = None  # K, with "tau_c" among the estimators
    dt: float | None = None  # the bands' frequency scale
    band_split: float | None = None

    @classmethod
    def of(cls, config: DaemonConfig) -> EngineSpec:
        """The daemon's engine for ``config``: its ``[estimator]``, τc when configured or needed
        by a region (``config.tau_c_on``) and the band split against ``camera.frame_interval_s``."""
        return cls.of_sections(config.estimator, tau_c=config.tau_c_on, **config.band_args)

    @classmethod
    def of_sections(cls, estimator: EstimatorSection, tau_c: bool = False, dt: float | None = None,
                    band_split: float | None = None, extra: Sequence[str] = ()) -> EngineSpec:
        """The engine of an ``[estimator]`` section; ``extra``: more maps to keep sums for (the
        timeline's descriptor columns, tune's candidates), after the section's."""
        maps = engine_estimators(estimator, False)
        maps = (*maps, *(name for name in extra if name not in maps and name != "tau_c"))
        return cls(window=estimator.window, lag=estimator.lag, q=estimator.engine_q, mode=estimator.mode,
                   estimators=(*maps, "tau_c") if tau_c else maps, max_lag=estimator.lags if tau_c else None,
                   dt=dt, band_split=band_split)

    @property
    def tau_c(self) -> bool:
        return "tau_c" in self.estimators

    @property
    def maps(self) -> tuple[str, ...]:
        """The maps (every estimator but τc, which is a fit, not a map of sums)."""
        return tuple(name for name in self.estimators if name != "tau_c")

    def replaced(self, **changes: object) -> EngineSpec:
        """The same spec with ``changes`` (window, lag, mode, ... ; without τc: max_lag None)."""
        spec = replace(self, **changes)  # type: ignore[arg-type]
        if not spec.tau_c and spec.max_lag is not None:
            spec = replace(spec, max_lag=None)
        return spec

    def engine(self, shape: tuple[int, int], bits: int | None, threads: int | None = None) -> SlidingWindow:
        """The engine over frames of ``shape`` (rows, columns) and ``bits`` (None: the dtype's)."""
        return SlidingWindow(shape, window=self.window, lag=self.lag, q=self.q, bits=bits,
                             estimators=self.estimators, mode=self.mode, threads=threads, max_lag=self.max_lag,
                             dt=self.dt, band_split=self.band_split)
