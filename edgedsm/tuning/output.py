"""What ``edgedsm tune`` writes: the config snippet, the JSON summary, and the report (markdown and
two plots: the chosen activity with its thresholds, and timing error against cost for every
candidate); the last report, kept where the dashboard reads it (``device.commissioning_dir``)."""

from __future__ import annotations

import datetime
import json
import math
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from edgedsm.config import DaemonConfig
from edgedsm.estimators import registry
from edgedsm.plots import pyplot, seconds_axis
from edgedsm.tuning.candidates import IN_SECONDS, ROBUST_D_PRIME, Outcome, pareto
from edgedsm.tuning.series import KINETICS
from edgedsm.tuning.session import Result, skipped_states

#: the last report's files in device.commissioning_dir (the dashboard reads them: edgedsm.dashboard.commissioning)
LAST_SUMMARY, LAST_PLOTS = "summary.json", ("activity.png", "tradeoff.png")
THRESHOLD_KEYS = {"wet_above", "dry_below", "wet_below_s", "dry_above_s", "hysteresis", "min_dwell_s"}


def unit_suffix(estimator: str) -> str:
    """`` (unit)`` of an activity with a unit (the registry's; dimensionless ones: none)."""
    unit = registry.get(estimator).unit
    return "" if unit.startswith("1") else f" ({unit})"


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(float(value)) if isinstance(value, float) else str(value)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(item) for item in value) + "]"
    return json.dumps(str(value), ensure_ascii=False)  # a TOML basic string


def region_thresholds(outcome: Outcome, name: str) -> dict[str, float]:
    """The region table's threshold keys for the outcome (τc: in seconds)."""
    th = outcome.regions[name].thresholds
    if th.on_tau:
        pair = {"wet_below_s": 1.0 / th.wet_above, "dry_above_s": 1.0 / th.dry_below}
    else:
        pair = {"wet_above": th.wet_above, "dry_below": th.dry_below}
    return {key: float(f"{value:.4g}") for key, value in pair.items()} | {"hysteresis": th.hysteresis,
                                                                         "min_dwell_s": th.min_dwell_s}


def snippet(result: Result, config: DaemonConfig, command: str) -> str:
    """An ``[estimator]`` table and one ``[[regions]]`` table per region (geometry copied from the
    config, thresholds filled in), ready to paste into the daemon config."""
    chosen = result.chosen
    assert chosen is not None
    candidate = chosen.candidate
    lines = [f"# {command}", f"# {result.reason}.", "", "[estimator]",
             f"activity = {_toml_value(candidate.estimator)}",
             f"window = {candidate.setting.window}", f"lag = {candidate.setting.lag}",
             f"mode = {_toml_value(candidate.setting.mode)}",
             f"noise_floor = {_toml_value(candidate.noise_floor or candidate.estimator in IN_SECONDS)}"]
    if registry.get(candidate.estimator).needs_q_zero:  # Fujii, 200·S2 at q = 0: the config refuses another q
        lines.append("q = 0.0")
    series = next(s for s in result.series if s.setting == candidate.setting)
    if candidate.estimator == "tau_c" and series.max_lag is not None:
        lines.append(f"max_lag = {series.max_lag}")
    if candidate.estimator == KINETICS:
        lines += kinetics_tables(config)
    for region in config.regions:
        lines += ["", "[[regions]]"]
        fields = region.model_dump(mode="json", exclude_none=True)
        geometry = {key: value for key, value in fields.items()
                    if key not in THRESHOLD_KEYS and (key in region.model_fields_set or key in ("name", "shape"))}
        lines += [f"{key} = {_toml_value(value)}" for key, value in geometry.items()]
        lines += [f"{key} = {_toml_value(value)}" for key, value in region_thresholds(chosen, region.name).items()]
    return "\n".join(lines) + "\n"


def kinetics_tables(config: DaemonConfig) -> list[str]:
    """``[kinetics]`` on with the settings tune measured it with (the config's, else the daemon's
    defaults), and the config's ``[[kinetics.stages]]`` (the table replaces the config's whole)."""
    section = config.kinetics
    fields = section.model_dump(mode="json", exclude={"enabled", "stages"}, exclude_none=True)
    lines = ["", "[kinetics]", "enabled = true", *(f"{key} = {_toml_value(value)}" for key, value in fields.items())]
    for stage in section.stages:
        lines += ["", "[[kinetics.stages]]", f"name = {_toml_value(stage.name)}",
                  f"rate_below_hz = {_toml_value(stage.rate_below_hz)}"]
    return lines


def outcome_json(outcome: Outcome) -> dict[str, Any]:
    c = outcome.candidate
    return {"estimator": c.estimator, "noise_floor": c.noise_floor, "window": c.setting.window,
            "lag": c.setting.lag, "mode": c.setting.mode, "label": c.label(), "auc": outcome.auc,
            "d_prime": outcome.d_prime if math.isfinite(outcome.d_prime) else None,
            "delay_s": outcome.delay_s if math.isfinite(outcome.delay_s) else None,
            "timing_error_s": outcome.timing_error_s if math.isfinite(outcome.timing_error_s) else None,
            "false_per_hour": outcome.false_per_hour, "cost_ms_per_frame": outcome.cost_s * 1e3,
            "sound": outcome.sound, "robust": outcome.robust, "skips": list(skipped_states(outcome)),
            "regions": {name: {"auc": r.separation.auc, "delay_s": r.replay.delay_s,
                               "skips": list(r.replay.skipped),
                               "false_transitions": r.replay.false_transitions,
                               "transitions": [list(t) for t in r.replay.states],
                               "thresholds": region_thresholds(outcome, name)}
                        for name, r in outcome.regions.items()}}


def summary_json(result: Result) -> dict[str, Any]:
    front = pareto(result.outcomes)
    return {"run": result.run.name, "frames": result.run.count, "dt_s": result.run.dt,
            "wet_until_s": result.run.wet_until_s, "dry_from_s": result.run.dry_from_s,
            "seconds": result.seconds, "passes": [s.setting.label() for s in result.series],
            "skipped": [s.label() for s in result.skipped], "reason": result.reason,
            "recommended": outcome_json(result.chosen) if result.chosen is not None else None,
            "pareto": [o.candidate.label() for o in front],
            "candidates": [outcome_json(o) for o in result.outcomes],
            "not_scored": [{"label": c.label(), "why": why} for c, why in result.excluded]}


def plot_chosen(path: Path, result: Result) -> None:
    """The chosen activity of every region against time, its thresholds and the marks."""
    chosen = result.chosen
    assert chosen is not None
    plt = pyplot()
    series = next(s for s in result.series if s.setting == chosen.candidate.setting)
    fig, ax = plt.subplots(figsize=(8, 4))
    times = np.asarray(series.times)
    for name in series.values:
        values = series.array(name, chosen.candidate.variant)
        ax.plot(times, values, label=name)
        for key, value in region_thresholds(chosen, name).items():
            if key in ("wet_above", "dry_below", "wet_below_s", "dry_above_s"):
                ax.axhline(value, ls="--", lw=0.8, color="grey")
    for mark, text in ((result.run.wet_until_s, "wet until"), (result.run.dry_from_s, "dry from")):
        ax.axvline(mark, color="black", lw=0.8)
        ax.text(mark, ax.get_ylim()[1], f" {text}", va="top", fontsize=8)
    ax.set_xlabel("time (s)")
    ax.set_ylabel(chosen.candidate.label().split(",")[0] + unit_suffix(chosen.candidate.estimator))
    ax.set_title(f"{Path(result.run.name).name}: {chosen.candidate.label()}")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_tradeoff(path: Path, result: Result) -> None:
    """Timing error against cost per frame for every candidate that calls every region dry; the
    sound and robust ones filled, the sound ones of d′ < ROBUST_D_PRIME filled orange, the
    recommended one ringed."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for outcome in result.outcomes:
        if not math.isfinite(outcome.timing_error_s):
            continue
        fill = ("C0" if outcome.robust else "C1") if outcome.sound else "none"
        ax.scatter(outcome.cost_s, outcome.timing_error_s, s=18, facecolors=fill,
                   edgecolors="C0" if fill == "none" else fill)
    if result.chosen is not None:
        ax.scatter(result.chosen.cost_s, result.chosen.timing_error_s, s=120, facecolors="none",
                   edgecolors="C3", label=f"recommended: {result.chosen.candidate.label()}")
        ax.legend(fontsize=8)
    ax.set_xscale("log")
    seconds_axis(ax.xaxis)  # "6 ms", not "6×10⁻³"
    ax.set_xlabel("engine push per frame (measured)")
    ax.set_ylabel("worst |dry call - dry mark| (s)")
    ax.set_title(f"filled: separates, calls dry, no false transition; orange: d′ < {ROBUST_D_PRIME:g}", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def report(out: Path, result: Result, command: str) -> list[Path]:
    """report.md, activity.png and tradeoff.png in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    lines = [f"# Commissioning report: {result.run.name}", "", f"`{command}`: {result.run.count} frames, "
             f"Δt = {result.run.dt:g} s, wet until {result.run.wet_until_s:g} s, dry from "
             f"{result.run.dry_from_s:g} s; {len(result.series)} window settings in {result.seconds:.0f} s"
             + (f" ({len(result.skipped)} left out by the budget)" if result.skipped else "") + ".", "",
             f"**{result.reason}.**", ""]
    written = []
    if result.chosen is not None:
        plot_chosen(out / "activity.png", result)
        written.append(out / "activity.png")
        lines += ["![the chosen activity](activity.png)", ""]
    plot_tradeoff(out / "tradeoff.png", result)
    written.append(out / "tradeoff.png")
    lines += ["![timing error against cost](tradeoff.png)", "",
              "*skips*: states of wet → drying → dry the daemon with the candidate's thresholds did not show on "
              "this run before calling it dry (its drying band crossed within the dwell); such a candidate is not "
              "proposed.", "",
              "| candidate | AUC | d′ | dry call vs mark (s) | false /h | ms/frame | sound | robust | skips |",
              "|---|---|---|---|---|---|---|---|---|"]
    for outcome in sorted(result.outcomes, key=lambda o: (not o.sound, o.timing_error_s, o.cost_s)):
        delay = f"{outcome.delay_s:+.1f}" if math.isfinite(outcome.delay_s) else "never"
        d_prime = f"{outcome.d_prime:.1f}" if outcome.d_prime < 100 else "> 100"
        lines.append(f"| {outcome.candidate.label()} | {outcome.auc:.3f} | {d_prime} | {delay} | "
                     f"{outcome.false_per_hour:.1f} | {outcome.cost_s * 1e3:.3f} | {'yes' if outcome.sound else ''} | "
                     f"{'yes' if outcome.robust else ''} | {', '.join(skipped_states(outcome))} |")
    if result.excluded:
        lines += ["", "Not scored:", ""] + [f"- {c.label()}: {why}" for c, why in result.excluded]
    (out / "report.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    return [out / "report.md", *written]


def keep_last(folder: Path, result: Result, command: str, config: DaemonConfig) -> Path:
    """The report (report.md and its plots) and LAST_SUMMARY (:func:`summary_json` with the
    date, the command, the config and the device) in ``folder``, where the dashboard reads them.
    Each file is written aside and moved in whole, the summary last, so that a page reading
    meanwhile gets the old report or the new one, never a torn file."""
    partial = folder / ".partial"
    if partial.exists():
        shutil.rmtree(partial)
    written = report(partial, result, command)
    summary = summary_json(result) | {
        "written_at": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"), "command": command,
        "config": config.source, "device": config.device.name,
        "plots": [path.name for path in written if path.suffix == ".png"]}
    (partial / LAST_SUMMARY).write_text(json.dumps(summary, indent=1, ensure_ascii=False), encoding="utf-8")
    for name in (*LAST_PLOTS, "report.md", LAST_SUMMARY):
        if (partial / name).exists():
            os.replace(partial / name, folder / name)
        else:  # no recommendation: no activity plot; the last run's must not stay beside this summary
            (folder / name).unlink(missing_ok=True)
    partial.rmdir()
    return folder / LAST_SUMMARY
