"""``edgedsm bench accuracy``: the command, and the markdown tables and figures of what
:mod:`edgedsm_lab.bench.accuracy` measured (docs/accuracy.md)."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import numpy as np

from edgedsm.plots import pyplot
from edgedsm_lab.bench import accuracy
from edgedsm_lab.bench.accuracy import (
    CASES,
    DESCRIPTORS,
    ESTIMATORS,
    FULL,
    LABELS,
    LAGGED,
    MODES,
    NOISE,
    QUICK,
    STEP_FROM,
    STEP_TO,
    TAU_FAST,
    TAU_SLOW,
    Results,
    measure,
)
from edgedsm_lab.bench.report import Report, add_output_argument, load_average


def _f(value: float, digits: int = 3) -> str:
    return "n/a" if not np.isfinite(value) else f"{value:.{digits}g}"


def contrast_rows(results: Results, by: str, names: tuple[str, ...]) -> list[list[str]]:
    """One row per (noise, N or m): β and AUC per estimator of ``names`` (and ms/frame for N)."""
    rows_in = results.contrast_n if by == "N" else results.contrast_m
    keyed = {(noise, name, x): (beta, area) for noise, name, x, beta, area in rows_in}
    xs = sorted({x for _, _, x, _, _ in rows_in})
    rows = []
    for noise in ("clean", "noisy"):
        for x in xs:
            row = [noise, str(x)]
            for name in names:
                beta, area = keyed[noise, name, x]
                row.append(f"{beta:.3f} / {area:.3f}")
            if by == "N":
                row += [_f(results.cost["sliding", name, x], 2) for name in names]
            rows.append(row)
    return rows


def delay_rows(results: Results, names: tuple[str, ...], timed: tuple[str, ...]) -> list[list[str]]:
    """One row per (mode, N): the step delays of ``names``, the ms/frame of ``timed``; n/a where
    the engine does not offer the estimator in that mode."""
    rows = []
    keyed = {(mode, n, name): (d50, d90) for mode, n, name, d50, d90 in results.delays}
    for mode in MODES:
        for n in results.plan.step_windows:
            row = [mode, str(n)]
            for name in names:
                d50, d90 = keyed.get((mode, n, name), (float("nan"), float("nan")))
                row.append(f"{_f(d50)} / {_f(d90)}")
            row += [_f(results.cost.get((mode, name, n), float("nan")), 2) for name in timed]
            rows.append(row)
    return rows


def level_rows(results: Results) -> list[list[str]]:
    rows = []
    keyed = {(mode, n, name): (before, after) for mode, n, name, before, after in results.levels}
    for mode in MODES:
        for n in results.plan.step_windows:
            row = [mode, str(n)]
            for name in ESTIMATORS + DESCRIPTORS:
                before, after = keyed.get((mode, n, name), (float("nan"), float("nan")))
                row.append(f"{_f(before)} → {_f(after)}")
            rows.append(row)
    return rows


def smoothing_rows(results: Results) -> list[list[str]]:
    return [[kind, str(k), f"{c:.2f}", f"{a:.3f}", f"{w:.1f}", f"{ms:.2f}"]
            for kind, k, c, a, w, ms in results.smoothing]


def case_rows(results: Results) -> list[list[str]]:
    """One row per estimator: β / AUC in each case of CASES."""
    keyed = {(case, name): (beta, area) for case, name, beta, area in results.cases}
    return [[LABELS[name], *(f"{keyed[case, name][0]:.3f} / {keyed[case, name][1]:.3f}" for case in CASES)]
            for name in ESTIMATORS + DESCRIPTORS]


def write_cases(report: Report, results: Results) -> None:
    """The table of each disturbance alone (paper §2B) at one N."""
    plan = results.plan
    report.line("### 1c. Phase noise and ambient light, each alone")
    report.line()
    report.line(f"Each disturbance alone (the paper's §2B cases) and both, at N = {plan.window_for_lags}, "
                f"m = {plan.lag}: β / AUC of the logos against the background; phase noise "
                f"α = {NOISE['phase_noise']['alpha']} (white), ambient light η = {NOISE['ambient_light']['eta']}.")
    report.line()
    report.table(["estimator", *CASES], case_rows(results))
    report.line()


def _log_ticks(ax, values: tuple[int, ...]) -> None:
    """A log axis labelled with the swept values themselves."""
    ax.set_xscale("log")
    ax.set_xticks(list(values), [str(v) for v in values])
    ax.minorticks_off()


def _against_window(results: Results, colours: dict[str, str], names: tuple[str, ...],
                    label: Callable[[str, str], str], title: str, path: Path) -> Path:
    """β and AUC of ``names`` on the logo object against N, clean and noisy, saved to ``path``."""
    from matplotlib import pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2))
    for noise, style in (("clean", "-"), ("noisy", "--")):
        for name in names:
            pts = sorted((n, b, a) for nz, nm, n, b, a in results.contrast_n if nz == noise and nm == name)
            xs = [p[0] for p in pts]
            axes[0].plot(xs, [p[1] for p in pts], style, marker="o", color=colours[name], label=label(name, noise))
            axes[1].plot(xs, [p[2] for p in pts], style, marker="o", color=colours[name])
    for ax, heading in zip(axes, ("contrast β", "AUC (logo vs background)"), strict=True):
        _log_ticks(ax, results.plan.windows)
        ax.set_xlabel("window N (frames)")
        ax.set_title(heading)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8, ncol=2)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _figures(results: Results, folder: Path) -> dict[str, Path]:
    plt = pyplot()

    folder.mkdir(parents=True, exist_ok=True)
    out: dict[str, Path] = {}
    colours = {"s1": "tab:blue", "s2": "tab:orange", "s3": "tab:green", "tau_c": "tab:red", "fujii": "tab:olive",
               "gd": "tab:brown", "im": "tab:purple", "contrast": "tab:cyan"}

    out["contrast_n"] = _against_window(
        results, colours, ESTIMATORS, lambda name, noise: f"{LABELS[name]} {noise}",
        f"Logo object, m = {results.plan.lag}: solid without noise, dashed with noise",
        folder / "contrast-vs-window.png")
    out["descriptors_n"] = _against_window(
        results, colours, ("s2", "gd", "im", "contrast"),  # Fujii's β and AUC are S2's (200·S2)
        lambda name, noise: f"{LABELS[name]}{' = Fujii/200' if name == 's2' else ''} {noise}",
        f"The field's descriptors beside S2, m = {results.plan.lag}: solid without noise, dashed with noise",
        folder / "descriptors-vs-window.png")

    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for noise, style in (("clean", "-"), ("noisy", "--")):
        for name in ("s1", "s2", "s3", "im"):  # Fujii's β is S2's
            pts = sorted((m, b) for nz, nm, m, b, _ in results.contrast_m if nz == noise and nm == name)
            ax.plot([p[0] for p in pts], [p[1] for p in pts], style, marker="o", color=colours[name],
                    label=f"{LABELS[name]} {noise}")
    _log_ticks(ax, results.plan.lags)
    ax.set_xlabel("lag m (frames)")
    ax.set_ylabel("contrast β")
    ax.set_title(f"β against the lag, N = {results.plan.window_for_lags}")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=2)
    fig.tight_layout()
    out["contrast_m"] = folder / "contrast-vs-lag.png"
    fig.savefig(out["contrast_m"], dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(1, len(MODES), figsize=(13, 4), sharey=True)
    longest = max(results.plan.step_windows)
    for ax, mode in zip(axes, MODES, strict=True):
        for n in results.plan.step_windows:
            trace = results.traces[mode, n]
            ax.plot(np.arange(trace.size) - longest, trace, label=f"N = {n}")
        ax.axhline(0.5, color="grey", lw=0.8, ls=":")
        ax.axhline(0.9, color="grey", lw=0.8, ls=":")
        ax.axvline(0, color="black", lw=0.8)
        ax.set_title(f"{mode}")
        ax.set_xlabel("frames after the step")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("S1 progress (0 = before, 1 = settled)")
    axes[0].legend(fontsize=8)
    fig.suptitle(f"Step of τc {STEP_FROM:g} → {STEP_TO:g} Δt at frame 0")
    fig.tight_layout()
    out["step"] = folder / "step-response.png"
    fig.savefig(out["step"], dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    for kind, marker in (("box", "o"), ("gaussian", "s")):
        pts = [(w, c, k) for kd, k, c, _, w, _ in results.smoothing if kd == kind]
        ax.plot([p[0] for p in pts], [p[1] for p in pts], marker=marker, label=kind)
        for w, c, k in pts:
            ax.annotate(f"k={k}", (w, c), textcoords="offset points", xytext=(4, 4), fontsize=8)
    ax.set_xlabel("10–90 % edge width (px): lower is sharper")
    ax.set_ylabel("CNR of S2 (τc 10 vs 50 halves)")
    ax.set_title("Spatial smoothing: contrast-to-noise against resolution")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    out["smoothing"] = folder / "smoothing.png"
    fig.savefig(out["smoothing"], dpi=110)
    plt.close(fig)
    return out


#: the heading of docs/accuracy.md's section written from ``edgedsm bench light`` (not measured here)
LIGHT_SECTION = "## 5. "


def kept_from(path: Path) -> tuple[list[str], list[str]]:
    """From an earlier report at ``path``: its section 5 (written from ``edgedsm bench light``,
    docs/accuracy-light.md) and the how-to-choose rows that cite it, which this run does not
    measure and a regeneration keeps; ([], []) without that file or section."""
    lines = path.read_text(encoding="utf-8").splitlines() if path.exists() else []
    starts = [i for i, line in enumerate(lines) if line.startswith(LIGHT_SECTION)]
    if not starts:
        return [], []
    end = next((i for i in range(starts[0], len(lines)) if lines[i] == "## How to choose"), len(lines))
    rows = [line for line in lines[end:] if line.startswith("|") and "(table 5)" in line]
    return lines[starts[0]: end], rows


def write_report(report: Report, results: Results, load: float | None, command: str,
                 figures: Path | None, kept: tuple[list[str], list[str]] = ([], [])) -> None:
    """The whole report; ``kept``: section 5 and its how-to-choose rows (``kept_from``)."""
    plan = results.plan
    report.line(report.machine(command, "numba", "scipy", load=load, load_after=load_average()))
    report.line()
    report.line(f"Simulated scenes (edgedsm.sim): {plan.size}² pixels for contrast and smoothing, "
                f"{plan.step_size}² for the step; 8-bit detector with shot noise (N_max = 1000). "
                f"\"noisy\" adds white phase noise α = {NOISE['phase_noise']['alpha']} and ambient light "
                f"η = {NOISE['ambient_light']['eta']}. τc is fitted with K = {plan.max_lag} lags; its activity "
                f"is the rate 1/τc so that higher means more active for every column. ms/frame is one push of "
                f"the streaming engine (`SlidingWindow`, one estimator alone) on frames tiled to "
                f"{plan.cost_size}², measured in this run (load on the machine slows it at random).")
    report.line()
    paths = _figures(results, figures) if figures is not None else {}

    def figure(key: str, alt: str) -> None:
        if key in paths:
            report.line(f"![{alt}]({paths[key].parent.name}/{paths[key].name})")
            report.line()

    report.line("## 1. Contrast against the window N and the lag m")
    report.line()
    report.line(f"β and AUC (`β / AUC`) of the logos (τc = {TAU_FAST:g}) against the background "
                f"(τc = {TAU_SLOW:g}), m = {plan.lag}; then the engine's ms/frame per estimator at that N.")
    report.line()
    header = ["noise", "N", *(f"{LABELS[e]} β / AUC" for e in ESTIMATORS), *(f"{LABELS[e]} ms" for e in ESTIMATORS)]
    report.table(header, contrast_rows(results, "N", ESTIMATORS))
    report.line()
    figure("contrast_n", "beta and AUC against N")
    report.line(f"β / AUC against the lag m at N = {plan.window_for_lags} (τc has no lag: it fits lags up to K; "
                "GD and σ/⟨I⟩ use every frame of the window, no lag).")
    report.line()
    report.table(["noise", "m", *(f"{LABELS[e]} β / AUC" for e in LAGGED)], contrast_rows(results, "m", LAGGED))
    report.line()
    figure("contrast_m", "beta against m")
    report.line("### 1b. The field's descriptors")
    report.line()
    report.line("The field's descriptors (docs/descriptors.md) on the same frames: batch maps of "
                "`edgedsm.estimators.descriptors` (Fujii and IM at the lag m, GD over every pair of the window, "
                "σ/⟨I⟩ the temporal contrast); ms/frame is the engine with that descriptor alone (Fujii: q = 0).")
    report.line()
    report.table(["noise", "N", *(f"{LABELS[e]} β / AUC" for e in DESCRIPTORS),
                  *(f"{LABELS[e]} ms" for e in DESCRIPTORS)], contrast_rows(results, "N", DESCRIPTORS))
    report.line()
    figure("descriptors_n", "descriptors: beta and AUC against N")
    write_cases(report, results)
    report.line("## 2. Detection delay of a τc step")
    report.line()
    report.line(f"The whole surface steps from τc = {STEP_FROM:g} to {STEP_TO:g} Δt; frames after the step until "
                "the region value has gone 50 % / 90 % of the way to its settled value. The step falls on a "
                "tumbling block boundary (the best case: a step inside a block waits up to one more block).")
    report.line()
    report.table(["mode", "N", "S1 50 % / 90 %", "S3 50 % / 90 %", "τc 50 % / 90 %", "S1 ms", "τc ms"],
                 delay_rows(results, ("s1", "s3", "tau_c"), ("s1", "tau_c")))
    report.line()
    report.line("The descriptors through the same step, each in the modes the engine offers it (GD: measured "
                "sliding; tumbling keeps the same exact sum), and the engine's ms/frame for it alone in that mode.")
    report.line()
    report.table(["mode", "N", *(f"{LABELS[e]} 50 % / 90 %" for e in DESCRIPTORS),
                  *(f"{LABELS[e]} ms" for e in DESCRIPTORS)], delay_rows(results, DESCRIPTORS, DESCRIPTORS))
    report.line()
    figure("step", "step response per mode")
    report.line("## 3. Level portability")
    report.line()
    report.line(f"Settled region values before → after the step (τc {STEP_FROM:g} → {STEP_TO:g}; τc column in "
                "frames, the fitted τc itself). A `wet_above` threshold carries over between N and modes only "
                "where a column does not move. The issue measured S3 after a step at 0.81 / 0.64 / 0.53 for "
                "N = 50 / 100 / 200 sliding and 0.44 exponential (N = 200, Gaussian light); the trend here is the "
                "same. "
                "τc is reported in frames; the daemon publishes it in seconds (× Δt).")
    report.line()
    report.table(["mode", "N", *(LABELS[e] if e != "tau_c" else "τc" for e in ESTIMATORS + DESCRIPTORS)],
                 level_rows(results))
    report.line()
    report.line("## 4. Spatial smoothing against resolution")
    report.line()
    report.line(f"S2 map (N = {plan.window_for_lags}, m = {plan.lag}) of a sharp edge (left τc = {TAU_FAST:g}, "
                f"right τc = {TAU_SLOW:g}), smoothed with a k x k box or a Gaussian of σ = k/4 cut at ±k/2. "
                "CNR = difference of the half means / pooled standard deviation (10 px away from the edge); "
                f"edge width: 10–90 % of the row-averaged profile; ms per map at {plan.cost_size}².")
    report.line()
    report.table(["filter", "k", "CNR", "AUC", "edge width px", "ms/map"], smoothing_rows(results))
    report.line()
    figure("smoothing", "CNR against edge width")
    report.extend(kept[0])
    report.line("## How to choose")
    report.line()
    rows = how_to_choose(results)
    at = next(i + 1 for i, row in enumerate(rows) if row.startswith("| uneven laser light"))
    report.extend(rows[:at] + kept[1] + rows[at:] + descriptor_choices(results))


def how_to_choose(results: Results) -> list[str]:
    """The plant table, with the numbers of this run where they decide."""
    plan = results.plan
    levels = {(mode, n, name): after for mode, n, name, _, after in results.levels}
    delays = {(mode, n, name): (d50, d90) for mode, n, name, d50, d90 in results.delays}
    beta = {(noise, name, n): b for noise, name, n, b, _ in results.contrast_n}
    area = {(noise, name, n): a for noise, name, n, _, a in results.contrast_n}
    smooth = {(kind, k): (c, w) for kind, k, c, _, w, _ in results.smoothing}
    ns, mid, big = plan.step_windows, plan.step_windows[len(plan.step_windows) // 2], max(plan.windows)
    small = min(plan.windows)

    def join(values: list[float]) -> str:
        return " / ".join(_f(v) for v in values)

    def per_n(mode: str, which: int) -> str:
        return _f(delays[mode, mid, "s1"][which] / mid, 2)

    c1, w1 = smooth["box", 1]
    c3, w3 = smooth["box", 3]
    c5, w5 = smooth["box", 5]
    return [
        "| need | choose | why (this run) |",
        "|---|---|---|",
        f"| thresholds that survive a change of N or mode | τc in seconds (`tau_c`) | settled τc "
        f"{join([levels['sliding', n, 'tau_c'] for n in ns])} frames (true {STEP_TO:g}) at N = "
        f"{' / '.join(map(str, ns))}; S3 moves {join([levels['sliding', n, 's3'] for n in ns])}, and "
        f"{_f(levels['exponential', max(ns), 's3'])} exponential (table 3) |",
        f"| fastest alarm on a change | sliding, small N | S1 reaches 50 % / 90 % after {per_n('sliding', 0)} N / "
        f"{per_n('sliding', 1)} N sliding, {per_n('exponential', 0)} N / {per_n('exponential', 1)} N exponential; "
        "tumbling waits for the block to end (table 2) |",
        f"| separate two activity levels | S2 with N as long as the process allows | AUC of S2 "
        f"{_f(area['clean', 's2', small])} at N = {small} → {_f(area['clean', 's2', big])} at N = {big}; "
        f"β of S1/S2 does not grow with N, β of S3 does ({_f(beta['clean', 's3', small])} → "
        f"{_f(beta['clean', 's3', big])}) (table 1) |",
        "| choose the lag m | m of the order of the faster τc, smaller without vibration | β peaks near "
        "m = 2–5 without noise and near m = 10 with phase noise (lag table) |",
        f"| phase noise (vibration), ambient light | τc, N ≥ 200 | β of 1/τc {_f(beta['clean', 'tau_c', big])} "
        f"clean, {_f(beta['noisy', 'tau_c', big])} noisy at N = {big}, where S1 falls from "
        f"{_f(beta['clean', 's1', big])} to {_f(beta['noisy', 's1', big])}; at short N τc is unreliable |",
        "| uneven laser light | S2 or τc | S1 follows the light; S2 and τc are normalised |",
        "| a τc map per pixel | N ≥ 20·τc, K ≥ 2·τc | median of the (median-unbiased) map within 20 % of "
        "τc at N = 20·τc, -18 … +7 % for τc = 2…50 with and without noise, -8 … -1 % at 80·τc; region "
        "values within 5 % (docs/tau_c.md, per-pixel validation) |",
        "| least memory at large N | exponential (S1-S3) or tumbling | an m-frame or (m+1)-frame ring instead "
        "of N frames (docs/bench-engine.md) |",
        f"| noisy maps, regions larger than a few px | box smoothing k = 3–5 | CNR {c1:.1f} → {c3:.1f} (k = 3) → "
        f"{c5:.1f} (k = 5) while the edge widens {w1:.1f} → {w3:.1f} → {w5:.1f} px (table 4) |",
    ]


def descriptor_choices(results: Results) -> list[str]:
    """The how-to-choose rows of the field's descriptors, with this run's numbers."""
    plan = results.plan
    small, big, mid = min(plan.windows), max(plan.windows), plan.window_for_lags
    pair = {(noise, name, n): (b, a) for noise, name, n, b, a in results.contrast_n}
    case = {(c, name): (b, a) for c, name, b, a in results.cases}
    levels = {(mode, n, name): after for mode, n, name, _, after in results.levels}

    def ms(name: str, n: int) -> str:
        return _f(results.cost.get(("sliding", name, n), float("nan")), 2)

    def auc_of(name: str, noise: str = "clean", n: int = big) -> str:
        return _f(pair[noise, name, n][1])

    def beta_of(name: str, noise: str = "clean", n: int = big) -> str:
        return _f(pair[noise, name, n][0])

    gd_times = results.cost["sliding", "gd", big] / results.cost["sliding", "s1", big]
    steps = " / ".join(_f(levels["sliding", n, "contrast"]) for n in plan.step_windows)
    return [
        f"| report what papers report (Fujii) | `fujii` (engine: q = 0; all modes) | 200·S2: S2's β and AUC "
        f"(AUC {auc_of('fujii')} (S2 {auc_of('s2')}) at N = {big} clean, {auc_of('fujii', 'noisy')} "
        f"(S2 {auc_of('s2', 'noisy')}) noisy) and S2's sums: {ms('fujii', mid)} ms/frame (S2 {ms('s2', mid)}) at "
        f"N = {mid} (tables 1, 1b) |",
        f"| GD, the field's most cited descriptor | `gd`, N of a few τc; sliding or tumbling | every pair of the "
        f"window: once N ≫ τc both levels decorrelate inside it and GD reads the intensity spread, so its AUC falls "
        f"with N ({auc_of('gd', n=small)} → {auc_of('gd')} at N = {small} → {big}; S2 {auc_of('s2', n=small)} → "
        f"{auc_of('s2')}); β {beta_of('gd', n=small)} → {beta_of('gd')}; "
        f"its push is O(N): {ms('gd', small)} → {ms('gd', big)} ms/frame, {gd_times:.0f}× S1 "
        f"at N = {big} (table 1b) |",
        f"| weigh large jumps more than small ones | `im` (all modes) | squared differences: β {beta_of('im')} "
        f"(S1 {beta_of('s1')}), AUC {auc_of('im')} (S1 {auc_of('s1')}) clean, {auc_of('im', 'noisy')} "
        f"(S1 {auc_of('s1', 'noisy')}) noisy at N = {big}; phase noise alone AUC {_f(case['clean', 'im'][1])} → "
        f"{_f(case['phase noise', 'im'][1])} at N = {mid}; one more sum: {ms('im', mid)} ms/frame "
        f"(S1 {ms('s1', mid)}) (tables 1b, 1c) |",
        f"| the temporal speckle contrast σ/⟨I⟩ of the literature | `contrast` (all modes), short N, not for "
        f"thresholds across N | it tells the levels apart only through its finite-window bias (a slow pixel's "
        f"σ is underestimated in a short window): AUC {auc_of('contrast', n=small)} → {auc_of('contrast')} at "
        f"N = {small} → {big}; settled level after the step {steps} at N = "
        f"{' / '.join(map(str, plan.step_windows))}; ambient light alone β {_f(case['clean', 'contrast'][0])} → "
        f"{_f(case['ambient light', 'contrast'][0])}; no sum of its own: {ms('contrast', mid)} ms/frame "
        f"(tables 1b, 1c, 3) |",
    ]


# ----------------------------------------------------------------------------- command
HELP = accuracy.HELP
#: the command's --help text: what the benchmark measures (the measuring module's docstring)
DESCRIPTION = accuracy.__doc__


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true", help="small frames and short sweeps (about a minute)")
    add_output_argument(parser, "docs/accuracy.md")


def run(args: argparse.Namespace) -> int:
    load = load_average()
    plan = QUICK if args.quick else FULL
    results = measure(plan)
    report = Report("Accuracy against time")
    figures = Path(args.output).with_suffix("") if args.output else None
    kept = kept_from(Path(args.output)) if args.output else ([], [])
    write_report(report, results, load, "edgedsm bench accuracy" + (" --quick" if args.quick else ""), figures,
                 kept)
    if args.output:
        report.save(args.output)
    return 0
