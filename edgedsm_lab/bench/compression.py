"""What compression costs: lossless ratio and MB/s per core at 8, 12 and 16 bits, and what lossy
codecs take from the activity maps (docs/compression.md).

Speckle frames of the simulator's logo scene (the paper's two-level object) go through every
codec of imagecodecs that fits recordings:

  1. lossless (deflate, zstd, LZW, each also after TIFF's horizontal predictor; PNG, JPEG-LS,
     lossless JPEG, JPEG 2000 and HTJ2K reversible, JPEG-XL lossless, WebP lossless) at 8, 12 and
     16 bits: ratio, encode and decode MB/s on one core, a bit-identical check, and whether
     tifffile writes and reads that codec in a TIFF bit-identically;
  2. lossy (JPEG, JPEG 2000, WebP, JPEG-XL, several qualities each) on the 8-bit logo scene: ratio
     against what S1, S2, S3 and τc lose (relative RMS error against the uncompressed maps, β and
     AUC of the logos against the background, the regions' τc).

The measurement is edgedsm_lab.bench.compression_cost; this module prints the tables.

Examples:
  edgedsm bench compression --size 64 --frames 60 --repeats 1    # a quick look, under a minute
  edgedsm bench compression --output docs/compression.md         # 256², 200 frames, as the demo
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable

from edgedsm.errors import EdgedsmError
from edgedsm_lab.bench.accuracy import LABELS
from edgedsm_lab.bench.compression_cost import (
    DEPTHS,
    ESTIMATORS,
    REGIONS,
    LosslessRow,
    LossyRow,
    MapQuality,
    Plan,
    Results,
    Speed,
    measure,
)
from edgedsm_lab.bench.report import (
    Report,
    add_output_argument,
    cpu_sample,
    load_average,
    machine_use,
    markdown_table,
    others_share,
)

HELP = "what compression costs: lossless ratio and MB/s at 8/12/16 bits, lossy codecs against map accuracy"
PAPER_RATE_MB_S = 4096 * 2168 / 2.0 / 1e6  # the paper's series: 4096×2168 frames every Δt = 2 s, at 8 bits
NEED_MB_S = 100.0  # default: a 2048² 8-bit camera at 24 frames/s, half the daemon's zero-drop rate there
AUC_LOSS = 0.01  # a lossy setting keeps a map's contrast while its AUC falls by no more than this


def _f(value: float, digits: int = 3) -> str:
    return "n/a" if not math.isfinite(value) else f"{value:.{digits}g}"


def _mb(value: float) -> str:
    return "n/a" if not math.isfinite(value) else f"{value:.0f}" if value >= 10 else f"{value:.1f}"


def _pct(value: float) -> str:
    return f"{100 * value:.2f} %" if value < 0.1 else f"{100 * value:.1f} %"


def lossless_rows(results: Results, bits: int) -> list[list[str]]:
    return [[row.codec.name, row.codec.setting or "—", f"{row.ratio:.3f}", _mb(row.speed.encode_mb_s),
             _mb(row.speed.decode_mb_s), cpu_cells(row.speed),
             "yes" if row.identical else "**NO**", *tiff_cells(row)]
            for row in results.lossless if row.bits == bits]


def cpu_cells(speed: Speed) -> str:
    """'process ÷ thread CPU, encode / decode; thread CPU ÷ wall, encode / decode'."""
    return (f"{speed.encode.threads:.2f} / {speed.decode.threads:.2f}; "
            f"{speed.encode.on_cpu:.2f} / {speed.decode.on_cpu:.2f}")


def tiff_cells(row: LosslessRow) -> list[str]:
    """tifffile / OpenCV / Pillow reading the codec's TIFF back: "yes", "no" or "—"."""
    if row.tiff is None:
        return ["—", "—", "—"]
    if row.tiff.tifffile != "yes":
        return [row.tiff.tifffile, "—", "—"]
    return [row.tiff.tifffile, *("not installed" if ok is None else "yes" if ok else "no"
                                 for ok in (row.tiff.opencv, row.tiff.pillow))]


def depth_rows(results: Results) -> list[list[str]]:
    return [[str(d.bits), str(d.itemsize), str(d.levels), f"{d.entropy:.2f}", f"{d.entropy_ratio:.3f}"]
            for d in results.depths]


def lossy_cost_rows(results: Results) -> list[list[str]]:
    return [[row.codec.name, row.codec.setting, f"{row.ratio:.2f}", f"{row.frame_rms:.2f}",
             _mb(row.speed.encode_mb_s), _mb(row.speed.decode_mb_s),
             *(_pct(row.quality.error[name]) for name in ESTIMATORS)]
            for row in results.lossy]


def lossy_contrast_rows(results: Results) -> list[list[str]]:
    assert results.reference is not None
    rows = [["uncompressed", "—", *(f"{results.reference.beta[n]:.3f} / {results.reference.auc[n]:.4f}"
                                    for n in ESTIMATORS),
             *(f"{results.reference.region_tau[r]:.2f}" for r in REGIONS)]]
    for row in results.lossy:
        rows.append([row.codec.name, row.codec.setting,
                     *(f"{row.quality.beta[n]:.3f} / {row.quality.auc[n]:.4f}" for n in ESTIMATORS),
                     *(f"{row.quality.region_tau[r]:.2f}" for r in REGIONS)])
    return rows


def _tiff_ok(row: LosslessRow) -> bool:
    return row.identical and row.tiff is not None and row.tiff.tifffile == "yes"


def _everywhere(row: LosslessRow) -> bool:
    """tifffile, OpenCV and Pillow all read its TIFF back bit-identically."""
    return _tiff_ok(row) and row.tiff is not None and bool(row.tiff.opencv) and bool(row.tiff.pillow)


def by_label(results: Results) -> dict[str, dict[int, LosslessRow]]:
    """Lossless rows per codec label, then per bit depth."""
    table: dict[str, dict[int, LosslessRow]] = {}
    for row in results.lossless:
        table.setdefault(row.codec.label, {})[row.bits] = row
    return table


#: Codecs whose mean lossless ratio is within this fraction of the best one count as equally
#: good; the default is then the fastest of them.
RATIO_TOLERANCE = 0.02


def default_codec(results: Results, need_mb_s: float,
                  accept: Callable[[LosslessRow], bool] = _tiff_ok) -> dict[int, LosslessRow] | None:
    """One codec for every bit depth: among those ``accept`` takes at every depth (default: a TIFF
    that tifffile reads back bit-identically) and that encode at least ``need_mb_s`` on one core at
    every depth, those whose mean ratio over the depths is within ``RATIO_TOLERANCE`` of the best,
    and of these the fastest at its slowest depth (on speckle the ratios of the good codecs differ
    by a few per cent, their speeds by several times); None if none qualifies."""
    fit = [rows for rows in by_label(results).values()
           if set(rows) == set(DEPTHS) and all(accept(r) and r.speed.encode_mb_s >= need_mb_s
                                               for r in rows.values())]
    if not fit:
        return None

    def mean_ratio(rows: dict[int, LosslessRow]) -> float:
        return sum(r.ratio for r in rows.values()) / len(rows)

    best = max(mean_ratio(rows) for rows in fit)
    close = [rows for rows in fit if mean_ratio(rows) >= best * (1 - RATIO_TOLERANCE)]
    return max(close, key=lambda rows: min(r.speed.encode_mb_s for r in rows.values()))


def _codec_line(rows: dict[int, LosslessRow], results: Results) -> str:
    first = next(iter(rows.values()))
    bound = {d.bits: d.entropy_ratio for d in results.depths}
    readers = [name for name, ok in (("OpenCV", first.tiff and first.tiff.opencv),
                                     ("Pillow", first.tiff and first.tiff.pillow)) if ok]
    return (f"**{first.codec.label}**: ratio {' / '.join(f'{rows[b].ratio:.3f}' for b in DEPTHS)} at "
            f"{' / '.join(f'{b}' for b in DEPTHS)} bits "
            f"({' / '.join(f'{rows[b].ratio / bound[b]:.0%}' for b in DEPTHS)} of the order-0 entropy bound), encode "
            f"{' / '.join(_mb(rows[b].speed.encode_mb_s) for b in DEPTHS)} MB/s, decode "
            f"{' / '.join(_mb(rows[b].speed.decode_mb_s) for b in DEPTHS)} MB/s; its TIFF is read back by "
            f"tifffile{''.join(', ' + r for r in readers)}")


def keeps_auc(row: LossyRow, reference: MapQuality, estimator: str) -> bool:
    return row.quality.auc[estimator] >= reference.auc[estimator] - AUC_LOSS


def lossy_limit_rows(results: Results) -> list[list[str]]:
    """Per lossy codec and estimator: the highest-ratio setting whose AUC stays within AUC_LOSS."""
    assert results.reference is not None
    rows = []
    for name, settings in lossy_by_codec(results).items():
        row = [name]
        for estimator in ESTIMATORS:
            kept = [r for r in settings if keeps_auc(r, results.reference, estimator)]
            best = max(kept, key=lambda r: r.ratio, default=None)
            row.append("none" if best is None else f"{best.codec.setting} (×{best.ratio:.2f})")
        rows.append(row)
    return rows


def lossy_by_codec(results: Results) -> dict[str, list[LossyRow]]:
    table: dict[str, list[LossyRow]] = {}
    for row in results.lossy:
        if not row.codec.lossless:
            table.setdefault(row.codec.name, []).append(row)
    return table


def _recording_codec() -> str:
    """The codec recordings use by default, as this report names codecs."""
    from edgedsm.frameio.recording import CODECS, DEFAULT_CODEC

    compression, arguments = CODECS[DEFAULT_CODEC]
    return f"{compression} level {arguments['level']}" if "level" in arguments else str(compression)


def conclusions(results: Results, need_mb_s: float) -> list[str]:
    """The findings of this run, numbers from its tables."""
    lines = ["### Lossless: the default for recordings", ""]
    for bits in DEPTHS:
        rows = [row for row in results.lossless if row.bits == bits]
        stats = next((d for d in results.depths if d.bits == bits), None)
        if not rows or stats is None:
            continue
        best = max(rows, key=lambda row: row.ratio)
        fastest = max(rows, key=lambda row: row.speed.encode_mb_s)
        slow = [row.codec.label for row in rows if row.speed.encode_mb_s < PAPER_RATE_MB_S * stats.itemsize]
        lines.append(
            f"- **{bits} bits** (order-0 entropy allows ×{stats.entropy_ratio:.3f}): best ratio "
            f"{best.codec.label} ×{best.ratio:.3f} at {_mb(best.speed.encode_mb_s)} MB/s encode; fastest "
            f"encoder {fastest.codec.label} {_mb(fastest.speed.encode_mb_s)} MB/s at ×{fastest.ratio:.3f}. "
            + (f"Slower on one core than the paper's series ({PAPER_RATE_MB_S:.1f} MB/s at 8 bits, twice at "
               f"12/16): {', '.join(slow)}." if slow else "Every codec keeps up with the paper's series on one core."))
    lines.append("")
    chosen = default_codec(results, need_mb_s)
    lines.append(f"- One default for every depth (a TIFF that tifffile reads back, ≥ {need_mb_s:g} MB/s encode on "
                 f"one core at every depth, the fastest of those within {RATIO_TOLERANCE:.0%} of the best mean ratio): "
                 + (_codec_line(chosen, results) + "." if chosen else "none qualifies in this run.")
                 + f" `edgedsm record` and the daemon's recordings use {_recording_codec()} (`--codec`, "
                 "`[recording] codec`).")
    portable = default_codec(results, 0.0, _everywhere)
    lines.append(f"- Among TIFFs that OpenCV and Pillow read too, at any speed, the fastest within "
                 f"{RATIO_TOLERANCE:.0%} of their best mean ratio: "
                 + (_codec_line(portable, results) + "." if portable else "none in this run."))
    bad = [f"{row.codec.label} at {row.bits} bits" for row in results.lossless if not row.identical]
    lines += ["", "Every lossless codec gave back every pixel." if not bad else
              f"**Not bit-identical**: {', '.join(bad)}.", "", "### Lossy: what each setting costs", ""]
    assert results.reference is not None
    reference = results.reference
    lines.append(f"The highest ratio at which each map's AUC stays within {AUC_LOSS} of the uncompressed "
                 f"one ({' / '.join(f'{reference.auc[n]:.3f}' for n in ESTIMATORS)} for S1 / S2 / S3 / 1/τc):")
    lines.append("")
    lines.extend(markdown_table(["codec", *(LABELS[n] for n in ESTIMATORS)], lossy_limit_rows(results)))
    lines.append("")
    for name, rows in lossy_by_codec(results).items():
        text = f"- **{name}**:"
        for row in (rows[0], rows[-1]) if len(rows) > 1 else rows:
            text += (f" at {row.codec.setting} (×{row.ratio:.2f}) S1/S2/S3/τc map errors "
                     f"{' / '.join(_pct(row.quality.error[n]) for n in ESTIMATORS)}, AUC of S2 "
                     f"{row.quality.auc['s2']:.3f};")
        lines.append(text.rstrip(";") + ".")
    return lines


def write_report(report: Report, results: Results, command: str, header: str, need_mb_s: float) -> None:
    plan = results.plan
    report.line(header)
    report.line()
    report.line("The paper asks that outdoor acquisition allow raw-data compression, \"mandatory when storage of "
                "large amount of data is required\"; its ref. 25 (Stoykova et al., \"Intensity-based dynamic "
                "speckle method using JPEG and JPEG2000 compression\", Appl. Opt. 61, B287-B296, 2022) studies "
                "the lossy side. Here both sides are measured on the simulator's logo scene (letters IOMT and "
                "ETRI at τc = 10 Δt on a τc = 50 Δt background, speckle 2 px, shot noise with N_max = 1000 "
                f"photons), {plan.size}² pixels, changing only `[detector] bits`.")
    report.line()
    report.line(f"Speed is MB/s (10⁶ bytes) of raw frames per CPU second of the thread that calls the codec: "
                "imagecodecs calls each codec once per frame on that thread, and the codecs that have a thread "
                "option (OpenJPEG, libjxl, libwebp) get `numthreads=1`, so this is the rate of one core. CPU "
                "time rather than wall time, because the machine is shared: the wall clock also counts the time "
                "other work held the core. Median of "
                f"{plan.repeats} passes over {plan.speed_frames} frames after one warm-up frame. The column "
                "*threads; on CPU*: the process's CPU time ÷ the calling thread's (1.00: no other thread "
                "helped, which a per-core figure needs), then the thread's CPU time ÷ the wall time (below 1: "
                "other work took the core part of the time). Ratio = raw bytes / compressed bytes, raw being 1 "
                "byte per pixel at 8 bits and 2 (the uint16 a camera delivers) at 12 and 16. TIFF: tifffile "
                "wrote the frames as a multi-page TIFF with that codec and read them back bit-identically; "
                "OpenCV (cv2.imdecodemulti, its own libtiff) and Pillow read the same file, every page "
                "compared (`—`: TIFF has no such compression). A recorder can use several cores by "
                "compressing frames in parallel; the figures are per core.")
    report.line()
    report.line(f"Absent from this imagecodecs build: {', '.join(results.absent)}; their rows are missing."
                if results.absent else "Every codec below is in this imagecodecs build (none of them is absent).")
    report.line()
    report.line("## What the frames hold")
    report.line()
    report.table(["bits", "bytes/pixel", "distinct grey levels", "order-0 entropy, bits/pixel",
                  "ratio at that entropy"], depth_rows(results))
    report.line()
    report.line("The simulated detector counts whole photons (N_max = 1000 at the brightest pixel of frame 1) "
                "and maps them linearly onto the grey range, so at 12 and 16 bits the frames use the same few "
                "hundred levels, spread out: 16-bit frames hold no more information than 12-bit ones. "
                "Codecs that model which levels occur (JPEG-XL's palette) gain from it; byte-stream codecs "
                "(deflate, zstd, LZW) see the spread-out low byte as noise. A real sensor adds read noise "
                "that fills the gaps: on its 12/16-bit frames expect lower ratios, from JPEG-XL above all. "
                "The order-0 entropy treats pixels as independent; speckle of 2 px grains is not quite, so a "
                "codec that models neighbours (JPEG-XL at effort 7) can beat that bound a little.")
    report.line()
    report.line("## Lossless codecs")
    report.line()
    for bits in DEPTHS:
        report.line(f"### {bits} bits")
        report.line()
        report.table(["codec", "setting", "ratio", "encode MB/s", "decode MB/s", "threads; on CPU (enc / dec)",
                      "bit-identical", "TIFF: tifffile", "OpenCV", "Pillow"], lossless_rows(results, bits),
                     "llrrrrllll")
        report.line()
    report.line("## Lossy codecs and what the maps lose")
    report.line()
    report.line(f"Measured at 8 bits, the depth of the paper's simulated frames (§2A: 8-bit bitmaps): the logo "
                f"scene, {plan.frames} frames; S1, S2, S3 at m = {plan.lag} over all of them "
                f"(paper Eq. 1-3), τc fitted with K = {plan.max_lag} lags (edgedsm.estimators.tau_c). Errors "
                "are the relative RMS difference of each map from the decoded frames against the same map "
                "from the original frames, ‖map − map₀‖ / ‖map₀‖ over all pixels (τc in frames). Frame RMS: "
                "grey levels between decoded and original frames. WebP encodes RGB only: the grey frame goes "
                "in all three channels and the ratio counts one. JPEG 2000's setting is OpenJPEG's quality "
                "layer, the PSNR it aims at. The zstd row is a lossless control: its errors must be zero.")
    report.line()
    report.table(["codec", "setting", "ratio", "frame RMS", "encode MB/s", "decode MB/s",
                  *(f"{LABELS[n] if n != 'tau_c' else 'τc'} error" for n in ESTIMATORS)],
                 lossy_cost_rows(results), "llrrrrrrrr")
    report.line()
    report.line("β (paper §2C: (S_logos − S_background) / S_logos) and AUC (probability that a logo pixel reads "
                "higher than a background pixel) per map, `β / AUC`; for τc of the rate 1/τc, so that higher "
                f"means more active in every column. Then the regions' τc in frames (true: 10 in the letters, "
                f"50 in the background, which reads as K = {plan.max_lag} when it decorrelates beyond K lags).")
    report.line()
    report.table(["codec", "setting", *(f"{LABELS[n]} β / AUC" for n in ESTIMATORS),
                  *(f"τc {r}" for r in REGIONS)], lossy_contrast_rows(results), "ll" + "r" * 7)
    report.line()
    report.line("## Conclusions")
    report.line()
    report.extend(conclusions(results, need_mb_s))
    report.line()
    report.line("Why the normalised maps lose most: S2 (Eq. 2) divides each difference by I_i + I_(i+m), and "
                "speckle intensity is exponentially distributed, so many pixels sit within a few grey levels of "
                "zero, where a codec's error of one or two levels changes a term by a large fraction (a pair "
                "0, 0 adds 0; decoded as 1, 2 it adds 1/3). S3 (Eq. 3-4) divides S1 by the pixel's own σ, which "
                "a codec that smooths the frame lowers. S1 and τc, which take differences and correlations of "
                "the raw levels, keep their contrast far longer. The paper's ref. 25 studies the same question "
                "on measured speckle; the numbers here are the simulator's.")
    report.line()
    report.line(f"Thresholds of these conclusions: a lossless default must encode ≥ {need_mb_s:g} MB/s on one "
                f"core at every depth (`--need-mb-s`; {NEED_MB_S:g} is a 2048² 8-bit camera at 24 frames/s, half "
                "the rate the daemon takes there without drops, docs/bench-e2e.md) and be a TIFF compression "
                f"that tifffile reads back; a lossy setting keeps a map's contrast while its AUC falls by no more "
                f"than {AUC_LOSS}. Lossless is the default; a lossy codec is opt-in, and whoever chooses one should "
                "quote its row here.")


# ----------------------------------------------------------------------------- command
def add_arguments(parser: argparse.ArgumentParser) -> None:
    default = Plan()
    parser.add_argument("--size", type=int, default=default.size, help=f"pixels per side (default {default.size})")
    parser.add_argument("--frames", type=int, default=default.frames,
                        help=f"frames per lossy trial, the maps' window N (default {default.frames})")
    parser.add_argument("--speed-frames", type=int, default=default.speed_frames,
                        help=f"frames per timed pass and per lossless ratio (default {default.speed_frames})")
    parser.add_argument("--repeats", type=int, default=default.repeats,
                        help=f"timed passes, the median counts (default {default.repeats})")
    parser.add_argument("--lag", type=int, default=default.lag, help=f"lag m of S1-S3 (default {default.lag})")
    parser.add_argument("--max-lag", type=int, default=default.max_lag, help=f"K of τc (default {default.max_lag})")
    parser.add_argument("--need-mb-s", type=float, default=NEED_MB_S,
                        help=f"encode MB/s per core a lossless default must reach (default {NEED_MB_S:g})")
    add_output_argument(parser, "docs/compression.md")


def run(args: argparse.Namespace) -> int:
    try:
        plan = Plan(size=args.size, frames=args.frames, speed_frames=args.speed_frames, repeats=args.repeats,
                    lag=args.lag, max_lag=args.max_lag)
    except ValueError as exc:
        raise EdgedsmError(f"bench compression: {exc}") from None
    load, before = load_average(), cpu_sample()
    results = measure(plan, progress=lambda text: print(f"  {text}", file=sys.stderr, flush=True))
    command = ("edgedsm bench compression"
               + "".join(f" --{name.replace('_', '-')} {getattr(plan, name)}" for name in vars(plan)
                         if getattr(plan, name) != getattr(Plan(), name))
               + (f" --need-mb-s {args.need_mb_s:g}" if args.need_mb_s != NEED_MB_S else ""))
    report = Report("What compression costs")
    header = (report.machine(command, "imagecodecs", "tifffile", load=load, load_after=load_average())
              + machine_use(others_share(before, cpu_sample()), load))
    write_report(report, results, command, header, args.need_mb_s)
    if args.output:
        report.save(args.output)
    return 0
