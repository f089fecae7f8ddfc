"""The one registry of the maps edgedsm forms: what each is, what it needs and how it is judged.

Every map (the paper's S1-S3 and τc, the field's descriptors of docs/descriptors.md) has one
frozen :class:`Record` here: its name, unit and label, the engine sums and per-pixel values it is
formed from, the window modes the streaming engine forms it in (and the one statement of why not
in the others), whether it takes the lag m, its per-pixel value (numba) and NumPy twin, its noise
floor (or none), its batch reference and BSLTL name, and its cost class. The config's activity
choices, the engine's map names and mode checks, the kernels' :class:`KernelSpec`, the region
statistics, the noise summary, ``analyze --estimator``'s names (``descriptors.DESCRIPTORS``),
tune's candidates and the docs' table (docs/descriptors.md) are all derived from it.

Pure and cheap to import (no numba, no numpy): the functions a record names are references
"module:attribute", imported on first use (:func:`load`).

How to add a descriptor: one record plus its formula and tests.

1. Write its formula once: a batch reference over an (N, H, W) stack (``descriptors.py``, tested
   against BSLTL or the paper), and, to stream it, either a per-pixel value in
   :mod:`edgedsm.estimators.activity` with its NumPy twin (formed in the engine's fused maps pass:
   then name its slot in :data:`VALUES` and its flag in :class:`KernelSpec`) or, simplest, a NumPy
   ``derive`` function of the fused pass's values (``inputs``): the engine, snapshots and region
   statistics then form it from those values with no kernel change.
2. Add its :class:`Record` to :data:`_RECORDS` below (or, in a test, :func:`registered`).
3. Its noise floor, if the physics gives one, is a function of :mod:`edgedsm.estimators.noise_floor`
   named by ``floor``; without one the daemon judges it plainly.
4. Tests: its batch reference against an independent computation, the engine's map against the
   batch reference in every mode it allows; :func:`markdown_table` is the registry's table in
   docs/descriptors.md (``python -c "from edgedsm.estimators.registry import markdown_table as t;
   print(t(), end='')"``; tests/unit/estimators/test_registry_docs.py checks the docs carry it).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, fields
from typing import Any

#: The engine's window modes (docs/engine.md).
MODES: tuple[str, ...] = ("sliding", "exponential", "tumbling")
#: The modes that keep a finite window of frames.
WINDOW_MODES = frozenset({"sliding", "tumbling"})

#: The per-pixel values the engine's fused maps pass forms (``activity.pixel_values``), in its
#: order: the maps kernel's output arrays. "sigma" (Eq. 4) is no map of its own.
VALUES: tuple[str, ...] = ("s1", "s2", "s3", "sigma", "contrast", "fujii", "im")

#: GD's exact pair sum Σ_{i<j} |I_i - I_j| (int64): the engine's array and the snapshot's sum carry
#: the name of the map it forms.
PAIR_SUM = "gd"
#: The engine's sums a record may need: Σ|ΔI| ("abs", Eq. 1), the S2 terms ("ratio", Eq. 2), ΣI and
#: ΣI² ("total", "total_sq"; exponential mode: "mean", "m2"), Σ(ΔI)² ("sq"), GD's pair sum
#: (:data:`PAIR_SUM`), the DFT bins ("bins") and τc's lag products ("products").
SUMS = frozenset({"abs", "ratio", "total", "total_sq", "sq", PAIR_SUM, "bins", "products"})

#: Cost classes per pixel per pushed frame: O(1) (a few running sums), O(N) (reads the window),
#: O(B) (B DFT bins), O(K) (K lag products), O(R) (R reference frames, per measure); "batch": no
#: streaming form.
COSTS = ("O(1)", "O(N)", "O(B)", "O(K)", "O(R)", "batch")

#: How each family of maps is formed by the engine: the fused maps pass ("fused"), NumPy from the
#: fused pass's values ("derived"), GD's exact pair sum ("pair_sum"), the DFT bins ("bins"), τc's
#: fit ("tau"), or not at all ("batch"); "kinetics": no map and not the engine's, a per-region
#: estimator with reference frames of its own (edgedsm.estimators.kinetics), beside the engine
#: in every window mode (docs/kinetics.md).
SOURCES = ("fused", "derived", "pair_sum", "bins", "tau", "kinetics", "batch")
#: The sources of region-level measures: no engine sums, no map, formed in every window mode.
REGION_SOURCES = frozenset({"kinetics"})


def load(ref: str) -> Callable[..., Any]:
    """The function a reference "package.module:attribute" names (imported now)."""
    module, _, attribute = ref.partition(":")
    return getattr(importlib.import_module(module), attribute)


@dataclass(frozen=True)
class Record:
    """One map: what it is, what it needs, how it is computed, judged and costed."""

    name: str
    unit: str  # "grey levels", "1", "s", "grey levels²"
    label: str  # short, for tables, plots and tune's reasons: "S1", "contrast", "GD"
    summary: str  # its formula in one line
    source: str  # one of SOURCES
    sums: frozenset[str]  # the engine sums it is formed from (SUMS)
    inputs: tuple[str, ...] = ()  # the fused pass's values (VALUES) it is formed from
    modes: frozenset[str] = frozenset()  # the window modes the engine forms it in (empty: batch only)
    mode_reason: str = ""  # why not in the other modes ("{mode}": the mode refused; "" when in all)
    mode_subject: str = ""  # who needs the mode, with the verb (default: "<name> needs")
    uses_lag: bool = False  # depends on the lag m
    activity: bool = False  # the daemon can judge drying on it (estimator.activity)
    paper: bool = False  # S1, S2, S3: always formed, published and reduced by the daemon
    needs_q_zero: bool = False  # formed at q = 0 only (Fujii: 200·S2 at q = 0)
    cost: str = "O(1)"  # one of COSTS
    cost_note: str = ""  # what the cost class means for this map
    value: str | None = None  # the per-pixel value (numba, ``activity``): reference
    value_numpy: str | None = None  # its NumPy twin over whole arrays: reference
    derive: str | None = None  # source "derived": NumPy function of the input values' arrays
    floor: str | None = None  # its noise floor (``noise_floor``): reference; None: judged plainly
    floor_args: tuple[str, ...] = ()  # the floor's keyword arguments beside (model, means, n): lag, q
    shared_floor: bool = False  # floor -> (Floor, static variance), judged through the signal's share
    above: str | None = None  # shared floors: the value above the noise (estimates..., floor, share)
    above_inputs: tuple[str, ...] = ()  # the region estimates ``above`` takes first, in order
    batch: str | None = None  # the batch reference (an (N, H, W) stack in, an (H, W) map out)
    batch_args: tuple[str, ...] = ()  # its keyword arguments among lag, q, dt, split, threshold
    bsltl: str | None = None  # the BSLTL 1.3.1 function it reproduces (None: not in BSLTL)

    def __post_init__(self) -> None:
        if self.source not in SOURCES:
            raise ValueError(f"{self.name}: source {self.source!r} is not one of {SOURCES}")
        if self.cost not in COSTS:
            raise ValueError(f"{self.name}: cost {self.cost!r} is not one of {COSTS}")
        if unknown := set(self.sums) - SUMS:
            raise ValueError(f"{self.name}: unknown sums {sorted(unknown)}")
        if unknown := set(self.inputs) - set(VALUES):
            raise ValueError(f"{self.name}: inputs {sorted(unknown)} are not values of the fused pass")
        if unknown := set(self.modes) - set(MODES):
            raise ValueError(f"{self.name}: unknown modes {sorted(unknown)}")
        if self.region_level:
            if self.modes or self.sums or self.inputs or self.floor is not None:
                raise ValueError(f"{self.name}: a region-level measure has no engine modes, sums, inputs or floor")
        elif (self.source == "batch") != (not self.modes):
            raise ValueError(f"{self.name}: a batch-only map has no modes, a streamed one at least one")
        if self.source == "derived" and (self.derive is None or not self.inputs):
            raise ValueError(f"{self.name}: a derived map names its derive function and its inputs")
        if self.source == "fused" and self.name not in VALUES:
            raise ValueError(f"{self.name}: a fused map is one of the fused pass's values {VALUES}")
        if self.shared_floor and (self.floor is None or self.above is None or not self.above_inputs):
            raise ValueError(f"{self.name}: a shared floor names its floor, its above-noise function and its inputs")
        if self.modes != frozenset(MODES) and self.modes and not self.mode_reason:
            raise ValueError(f"{self.name}: say why it is not formed in the other modes")

    @property
    def streams(self) -> bool:
        """The streaming engine forms it (in :attr:`modes`)."""
        return bool(self.modes)

    @property
    def region_level(self) -> bool:
        """A per-region measure with its own state (:data:`REGION_SOURCES`): no map, not the
        engine's, the daemon forms it beside the engine in every window mode."""
        return self.source in REGION_SOURCES

    @property
    def has_floor(self) -> bool:
        return self.floor is not None

    def q_for(self, q: float) -> float:
        """The q (Eq. 2's offset, grey levels) this map is formed at: 0 for one that needs it
        (Fujii: 200·S2 at q = 0), else ``q``."""
        return 0.0 if self.needs_q_zero else q

    def mode_problem(self, mode: str) -> str | None:
        """Why the engine cannot form this map in window ``mode`` (None: it can); the one
        statement of it (engine and config)."""
        if mode in self.modes or self.region_level:
            return None
        if not self.modes:
            return f"{self.name} is a batch map only (edgedsm analyze), the engine does not stream it"
        allowed = " or ".join(repr(m) for m in MODES if m in self.modes)
        why = self.mode_reason.format(mode=mode)
        return f"{self.mode_subject or self.name + ' needs'} mode {allowed}, not {mode!r} ({why})"

    def streaming(self) -> str:
        """Its streaming cost, in words (docs/descriptors.md's table)."""
        if self.region_level:
            return f"{self.cost} per region pixel per measure ({self.cost_note})"
        if not self.modes:
            return "batch only"
        modes = ", ".join(m for m in MODES if m in self.modes)
        return f"{self.cost} per pixel per frame ({modes}{'; ' + self.cost_note if self.cost_note else ''})"


@dataclass(frozen=True)
class KernelSpec:
    """Which values the engine's fused maps pass forms (the named seam of the kernels; numba
    compiles one variant per spec, the booleans folded in as constants). Fields are named after
    :data:`VALUES` (σ is formed with S3 or the contrast)."""

    s1: bool = False  # Σ|ΔI| read: S1 (S3 needs it too)
    s2: bool = False  # the S2 terms read: S2 (Fujii is formed from it)
    s3: bool = False
    contrast: bool = False
    fujii: bool = False
    im: bool = False

    @classmethod
    def of(cls, maps: Iterable[str]) -> KernelSpec:
        """The spec that forms every fused-pass input of ``maps`` (names outside the registry, the
        engine's multi-band "bands", need none)."""
        values = {value for name in maps if name in REGISTRY for value in REGISTRY[name].inputs}
        return cls(**{f.name: f.name in values for f in fields(cls)})

    @property
    def sigma(self) -> bool:
        """σ (Eq. 4) is formed: S3 and the contrast need it."""
        return self.s3 or self.contrast

    @property
    def flags(self) -> tuple[bool, bool, bool, bool, bool, bool]:
        """(s1, s2, s3, contrast, fujii, im): the literal booleans a compiled kernel takes."""
        return self.s1, self.s2, self.s3, self.contrast, self.fujii, self.im

    @property
    def any(self) -> bool:
        return any(self.flags)

    def formed(self) -> dict[str, bool]:
        """Which of :data:`VALUES` the pass writes, by name."""
        return {name: (self.sigma if name == "sigma" else getattr(self, name)) for name in VALUES}

    def sizes(self, pixels: int) -> dict[str, int]:
        """Pixels of each array of :data:`VALUES` the maps kernel writes (0: not formed)."""
        return {name: pixels if on else 0 for name, on in self.formed().items()}


def _lazy(name: str) -> str:
    return f"edgedsm.estimators.{name}"


_ACT, _NF, _DESC, _BATCH, _VS = (_lazy("activity"), _lazy("noise_floor"), _lazy("descriptors"), _lazy("batch"),
                                 _lazy("value_set"))
_EVERY = frozenset(MODES)
_WINDOWED = WINDOW_MODES
_GD_WHY = "its exact sum reads the window's frames, and the {mode} mode keeps none"
_BANDS_WHY = "a band's DFT bins need a finite window, and the {mode} mode keeps none; docs/engine.md"
_BANDS = "the frequency bands (band_low, band_high, band_ratio) need"
_TAU_WHY = "its finite-window bias correction has no {mode} counterpart"
_BANDS_COST = "B the bins of the smaller band, 16 bytes each (edgedsm.estimators.dft_bins)"
_SIGMA = frozenset({"total", "total_sq"})
_BAND: dict[str, Any] = {"source": "bins", "sums": frozenset({"bins"}) | _SIGMA, "modes": _WINDOWED,
                         "mode_reason": _BANDS_WHY, "mode_subject": _BANDS, "cost": "O(B)", "cost_note": _BANDS_COST}

_RECORDS: tuple[Record, ...] = (
    Record("s1", "grey levels", "S1", "Eq. 1: mean |I_k - I_{k+m}|", "fused", frozenset({"abs"}), ("s1",), _EVERY,
           uses_lag=True, activity=True, paper=True, value=f"{_ACT}:s1_value", value_numpy=f"{_ACT}:s1_values",
           floor=f"{_NF}:s1_floor", floor_args=("lag",), batch=f"{_BATCH}:s1", batch_args=("lag",),
           bsltl="graphavd (m = 1)"),
    Record("s2", "1", "S2", "Eq. 2: mean |I_k - I_{k+m}|/(I_k + I_{k+m} + q)", "fused", frozenset({"ratio"}),
           ("s2",), _EVERY, uses_lag=True, activity=True, paper=True, value=f"{_ACT}:s2_value",
           value_numpy=f"{_ACT}:s2_values", floor=f"{_NF}:s2_floor", floor_args=("lag", "q"),
           batch=f"{_BATCH}:s2", batch_args=("lag", "q")),
    Record("s3", "1", "S3", "Eq. 3-4: S1/σ", "fused", frozenset({"abs"}) | _SIGMA, ("s1", "s3"), _EVERY,
           uses_lag=True, activity=True, paper=True, value=f"{_ACT}:s3_value", value_numpy=f"{_ACT}:s3_values",
           floor=f"{_NF}:s1_floor_and_static_variance", floor_args=("lag",), shared_floor=True,
           above=f"{_NF}:s3_signal", above_inputs=("s3", "s1"), batch=f"{_BATCH}:s3", batch_args=("lag",)),
    Record("tau_c", "s", "τc", "correlation time: multi-tau fit of the window's autocorrelation (docs/tau_c.md)",
           "tau", frozenset({"total", "total_sq", "products"}), (), _WINDOWED, mode_reason=_TAU_WHY,
           mode_subject="τc needs", activity=True, cost="O(K)", cost_note="K the multi-tau lags up to max_lag"),
    Record("contrast", "1", "contrast", "σ/⟨I⟩ (temporal)", "fused", _SIGMA, ("contrast",), _EVERY, activity=True,
           cost_note="S3's sums", value=f"{_ACT}:contrast_value", value_numpy=f"{_ACT}:contrast_values",
           floor=f"{_NF}:contrast_floor_and_static_variance", shared_floor=True, above=f"{_NF}:contrast_signal",
           above_inputs=("contrast",), batch=f"{_DESC}:contrast", bsltl="stdcont"),
    Record("fujii", "1 (0..200)", "Fujii", "200 S2(q = 0)", "fused", frozenset({"ratio"}), ("s2", "fujii"), _EVERY,
           uses_lag=True, activity=True, needs_q_zero=True, cost_note="200 S2 at q = 0",
           value=f"{_ACT}:fujii_value", value_numpy=f"{_ACT}:fujii_values", floor=f"{_NF}:fujii_floor",
           floor_args=("lag",), batch=f"{_DESC}:fujii", batch_args=("lag",), bsltl="fujii"),
    Record("im", "grey levels²", "IM", "mean (I_k - I_{k+m})²", "fused", frozenset({"sq"}), ("im",), _EVERY,
           uses_lag=True, activity=True, cost_note="one more sum", value=f"{_ACT}:im_value",
           value_numpy=f"{_ACT}:im_values", floor=f"{_NF}:im_floor", floor_args=("lag",), batch=f"{_DESC}:im",
           batch_args=("lag",), bsltl="graphim (m = 1)"),
    Record("gd", "grey levels", "GD", "Σ_{i<j} |I_i - I_j| / C(N, 2)", "pair_sum", frozenset({PAIR_SUM}), (),
           _WINDOWED, mode_reason=_GD_WHY, activity=True, cost="O(N)", cost_note="reads the window's N frames",
           value_numpy=f"{_VS}:gd_of_sum", floor=f"{_NF}:gd_floor", batch=f"{_DESC}:gd", bsltl="gendiff"),
    Record("band_low", "grey levels²", "low band", "periodogram power in (0, split]", **_BAND,
           batch=f"{_DESC}:band_low", batch_args=("dt", "split")),
    Record("band_high", "grey levels²", "high band", "periodogram power in (split, Nyquist]", **_BAND,
           batch=f"{_DESC}:band_high", batch_args=("dt", "split")),
    Record("band_ratio", "1", "high / low band", "high-band power / (low-band power + q)", **_BAND, activity=True,
           batch=f"{_DESC}:band_ratio", batch_args=("dt", "split", "q")),
    Record("kinetics", "s", "τ (kinetics)", "decorrelation time: the age at which the region's normalised "
           "two-time correlation falls to 1/e, from reference frames at geometric ages (docs/kinetics.md)",
           "kinetics", frozenset(), activity=True, cost="O(R)",
           cost_note="R the reference frames kept; O(1) per push, every window mode; [kinetics]"),
    Record("skewness", "1", "skewness", "mean ((I - ⟨I⟩)/σ)³", "batch", frozenset(), cost="batch",
           batch=f"{_DESC}:skewness", bsltl="graphskew"),
    Record("kurtosis", "1", "kurtosis", "mean ((I - ⟨I⟩)/σ)⁴", "batch", frozenset(), cost="batch",
           batch=f"{_DESC}:kurtosis", bsltl="graphkurt"),
    Record("mhi", "1 (0..255)", "MHI", "Σ_j [|I_j - I_{j+1}| > U] 255 j / Σ j", "batch", frozenset(), cost="batch",
           batch=f"{_DESC}:mhi", batch_args=("threshold",), bsltl="graphmhi"),
)

#: Every map by name, in the registry's order (the order of tables, choices and map outputs).
REGISTRY: dict[str, Record] = {record.name: record for record in _RECORDS}


def get(name: str) -> Record:
    """The record of ``name``; KeyError naming the known maps."""
    try:
        return REGISTRY[name]
    except KeyError:
        raise KeyError(f"unknown map {name!r}; known: {', '.join(REGISTRY)}") from None


def records(**where: Any) -> tuple[Record, ...]:
    """The records, in registry order, whose fields (or properties) equal ``where``'s values,
    e.g. ``records(activity=True)``, ``records(streams=True)``."""
    return tuple(r for r in REGISTRY.values() if all(getattr(r, key) == value for key, value in where.items()))


def names(**where: Any) -> tuple[str, ...]:
    """The names of :func:`records` ``(**where)``."""
    return tuple(r.name for r in records(**where))


def activities() -> tuple[str, ...]:
    """The maps the daemon can judge drying on: ``estimator.activity``'s choices."""
    return names(activity=True)


def paper_maps() -> tuple[str, ...]:
    """S1, S2, S3: the maps the daemon always forms, publishes and reduces per region."""
    return names(paper=True)


def with_floor() -> tuple[str, ...]:
    """The maps with a noise floor (docs/noise.md): judged above it by default."""
    return tuple(r.name for r in REGISTRY.values() if r.has_floor)


def mode_problem(name: str, mode: str) -> str | None:
    """Why map ``name`` cannot stream in ``mode`` (None: it can)."""
    return get(name).mode_problem(mode)


def in_mode(maps: Iterable[str], mode: str) -> tuple[str, ...]:
    """Those of ``maps`` the engine forms in ``mode``."""
    return tuple(name for name in maps if get(name).mode_problem(mode) is None)


def register(record: Record) -> None:
    """Add ``record`` (a new name) to the registry: every derived choice, check and table sees it."""
    if record.name in REGISTRY:
        raise ValueError(f"map {record.name!r} is registered already")
    REGISTRY[record.name] = record


def unregister(name: str) -> Record:
    """Remove a registered map (tests); returns its record."""
    return REGISTRY.pop(name)


@contextmanager
def registered(record: Record) -> Iterator[Record]:
    """``record`` registered for the ``with`` block (tests)."""
    register(record)
    try:
        yield record
    finally:
        unregister(record.name)


def field_names() -> tuple[str, ...]:
    """The fields of :class:`Record` (for the docs' table and tests)."""
    return tuple(f.name for f in fields(Record))


def markdown_table() -> str:
    """The registry as the markdown table of docs/descriptors.md ("The registry")."""
    def cell(text: str | None) -> str:
        return "—" if not text else text.replace("|", "\\|")

    rows = ["| name | label | unit | definition | lag m | engine modes | cost per pixel per frame | noise floor | "
            "judged on (activity) | BSLTL |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in REGISTRY.values():
        modes = ", ".join(m for m in MODES if m in r.modes) or ("every (its own state)" if r.region_level
                                                                 else "batch only")
        floor = ("yes, through the signal's share" if r.shared_floor else "yes") if r.has_floor else "no"
        rows.append(f"| `{r.name}` | {cell(r.label)} | {cell(r.unit)} | {cell(r.summary)} | "
                    f"{'yes' if r.uses_lag else 'no'} | {modes} | {cell(r.cost)} | {floor} | "
                    f"{'yes' if r.activity else 'no'} | {cell(r.bsltl)} |")
    return "\n".join(rows) + "\n"

