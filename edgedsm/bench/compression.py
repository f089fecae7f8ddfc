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

The measurement is edgedsm.bench.compression_cost; this module prints the tables.

Examples:
  edgedsm bench compression --size 64 --frames 60 --repeats 1    # a quick look, under a minute
  edgedsm bench compression --output docs/compression.md         # 256², 200 frames, as the demo
"""

from __future__ import annotations

import argparse
import math
import sys

from edgedsm.bench.accuracy import LABELS
from edgedsm.bench.compression_cost import (
    DEPTHS,
    ESTIMATORS,
    REGIONS,
    LosslessRow,
    LossyRow,
    Plan,
    Results,
    measure,
)
from edgedsm.bench.report import Report, add_output_argument, cpu_sample, load_average, machine_use, others_share
from edgedsm.errors import EdgedsmError

HELP = "what compression costs: lossless ratio and MB/s at 8/12/16 bits, lossy codecs against map accuracy"
PAPER_RATE_MB_S = 4096 * 2168 / 2.0 / 1e6  # the paper's series: 4096×2168 8-bit frames every Δt = 2 s
NEED_MB_S = 100.0  # default: a 2048² 8-bit camera at 24 frames/s, half the daemon's zero-drop rate there
AUC_LOSS = 0.01  # a lossy setting "keeps the maps" if no estimator's AUC falls by more than this
ERROR_LOSS = 0.05  # ... and S2's relative RMS error stays below this


def _f(value: float, digits: int = 3) -> str:
    return "n/a" if not math.isfinite(value) else f"{value:.{digits}g}"


def _mb(value: float) -> str:
    return "n/a" if not math.isfinite(value) else f"{value:.0f}" if value >= 10 else f"{value:.1f}"


def _pct(value: float) -> str:
    return f"{100 * value:.2f} %" if value < 0.1 else f"{100 * value:.1f} %"


def lossless_rows(results: Results, bits: int) -> list[list[str]]:
    return [[row.codec.name, row.codec.setting or "—", f"{row.ratio:.3f}", _mb(row.speed.encode_mb_s),
             _mb(row.speed.decode_mb_s), f"{row.speed.encode_cpu:.2f} / {row.speed.decode_cpu:.2f}",
             "yes" if row.identical else "**NO**", row.tiff or "—"]
            for row in results.lossless if row.bits == bits]


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


def default_codec(results: Results, bits: int, need_mb_s: float) -> LosslessRow | None:
    """The best ratio among bit-identical codecs that tifffile round-trips in a TIFF and that
    encode at least ``need_mb_s`` on one core (None if none does)."""
    fit = [row for row in results.lossless if row.bits == bits and row.identical and row.tiff == "yes"
           and row.speed.encode_mb_s >= need_mb_s]
    return max(fit, key=lambda row: row.ratio, default=None)


def keeps_maps(row: LossyRow, results: Results) -> bool:
    """No estimator's AUC down by more than AUC_LOSS and S2's error under ERROR_LOSS."""
    assert results.reference is not None
    return (all(row.quality.auc[n] >= results.reference.auc[n] - AUC_LOSS for n in ESTIMATORS)
            and row.quality.error["s2"] < ERROR_LOSS)


def conclusions(results: Results, need_mb_s: float) -> list[str]:
    """The findings of this run, numbers from its tables."""
    lines = ["### Lossless: the default for recordings", ""]
    for bits in DEPTHS:
        rows = [row for row in results.lossless if row.bits == bits]
        if not rows:
            continue
        best = max(rows, key=lambda row: row.ratio)
        fastest = max(rows, key=lambda row: row.speed.encode_mb_s)
        chosen = default_codec(results, bits, need_mb_s)
        text = (f"- **{bits} bits**: best ratio {best.codec.label} {best.ratio:.3f} at "
                f"{_mb(best.speed.encode_mb_s)} MB/s encode; fastest encoder {fastest.codec.label} "
                f"{_mb(fastest.speed.encode_mb_s)} MB/s at ratio {fastest.ratio:.3f}. ")
        if chosen is None:
            text += f"No TIFF codec encodes {need_mb_s:g} MB/s on one core here."
        else:
            text += (f"Best ratio among TIFF codecs encoding ≥ {need_mb_s:g} MB/s on one core: "
                     f"**{chosen.codec.label}**, {chosen.ratio:.3f} at {_mb(chosen.speed.encode_mb_s)} MB/s "
                     f"encode / {_mb(chosen.speed.decode_mb_s)} MB/s decode.")
        slow = [row.codec.label for row in rows if row.speed.encode_mb_s < PAPER_RATE_MB_S * row.bits / 8]
        text += (f" Too slow on one core even for the paper's series ({PAPER_RATE_MB_S:.1f} MB/s at 8 bits): "
                 f"{', '.join(slow)}." if slow else
                 f" Every codec keeps up with the paper's series ({PAPER_RATE_MB_S:.1f} MB/s at 8 bits) on one core.")
        lines.append(text)
    bad = [f"{row.codec.label} at {row.bits} bits" for row in results.lossless if not row.identical]
    lines += ["", "Every lossless codec gave back every pixel." if not bad else
              f"**Not bit-identical**: {', '.join(bad)}.", "", "### Lossy: what each setting costs", ""]
    by_codec: dict[str, list[LossyRow]] = {}
    for row in results.lossy:
        if not row.codec.lossless:
            by_codec.setdefault(row.codec.name, []).append(row)
    assert results.reference is not None
    reference = results.reference
    for name, rows in by_codec.items():
        kept = [row for row in rows if keeps_maps(row, results)]
        best_kept = max(kept, key=lambda row: row.ratio, default=None)
        text = f"- **{name}**: "
        text += (f"up to {best_kept.codec.setting} (ratio {best_kept.ratio:.2f}) every AUC stays within "
                 f"{AUC_LOSS} and S2 within {_pct(ERROR_LOSS)}. " if best_kept else
                 f"no setting keeps every AUC within {AUC_LOSS} and S2 within {_pct(ERROR_LOSS)}. ")
        for row in (rows[0], rows[-1]) if len(rows) > 1 else rows:
            text += (f"At {row.codec.setting} (ratio {row.ratio:.2f}): S1/S2/S3/τc errors "
                     f"{' / '.join(_pct(row.quality.error[n]) for n in ESTIMATORS)}, AUC of S2 "
                     f"{row.quality.auc['s2']:.3f} and of 1/τc {row.quality.auc['tau_c']:.3f} (uncompressed "
                     f"{reference.auc['s2']:.3f} and {reference.auc['tau_c']:.3f}). ")
        lines.append(text.rstrip())
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
    report.line(f"Speed is MB/s (10⁶ bytes) of raw frames on one core: imagecodecs calls each codec once per "
                "frame on the calling thread, and the codecs that have a thread option (OpenJPEG, libjxl, "
                "libwebp) get `numthreads=1`; the CPU/wall column is process CPU seconds per wall second over "
                f"the timed passes (about 1.0 = one core busy; less = the machine's other work). Median of "
                f"{plan.repeats} passes over {plan.speed_frames} frames after one warm-up frame. Ratio = raw "
                "bytes / compressed bytes, raw being 1 byte per pixel at 8 bits and 2 (the uint16 a camera "
                "delivers) at 12 and 16. TIFF: tifffile wrote the frames as a multi-page TIFF with that codec "
                "and read them back bit-identically (`—`: TIFF has no such compression). A recorder can use "
                "several cores by compressing frames in parallel; the figures are per core.")
    if results.absent:
        report.line()
        report.line(f"Absent from this imagecodecs build: {', '.join(results.absent)}.")
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
                "Speckle (fully developed, 2 px grains, shot noise) is close to independent pixels, so the "
                "order-0 entropy is about what any lossless codec can reach.")
    report.line()
    report.line("## Lossless codecs")
    report.line()
    for bits in DEPTHS:
        report.line(f"### {bits} bits")
        report.line()
        report.table(["codec", "setting", "ratio", "encode MB/s", "decode MB/s", "CPU/wall enc / dec",
                      "bit-identical", "TIFF (tifffile)"], lossless_rows(results, bits), "llrrrrll")
        report.line()
    report.line("## Lossy codecs and what the maps lose")
    report.line()
    report.line(f"8-bit logo scene, {plan.frames} frames; S1, S2, S3 at m = {plan.lag} over all of them "
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
    report.line(f"Thresholds of these conclusions: a lossless default must encode ≥ {need_mb_s:g} MB/s on one "
                f"core (`--need-mb-s`; {NEED_MB_S:g} is a 2048² 8-bit camera at 24 frames/s, half the rate the "
                "daemon takes there without drops, docs/bench-e2e.md) and be a TIFF compression that tifffile "
                f"reads back; a lossy setting keeps the maps while no AUC falls by more than {AUC_LOSS} and the S2 "
                f"map moves by less than {_pct(ERROR_LOSS)} RMS. Lossless is the default; a lossy codec is opt-in, "
                "and whoever chooses one should quote its row here.")


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
