"""Compute an activity map S1, S2 or S3 (paper Eq. 1-4), or another descriptor of the field,
from recorded frames.

FRAMES is anything edgedsm reads: a .npy stack, a multi-page TIFF or BigTIFF (compressed or
not), an edgedsm recording (`edgedsm record`), a video (AVI, MP4, MKV, MOV; a lossy codec is
analysed with a warning), an image folder or a pattern such as frames/%05d.png (natural
numeric order: img_2 before img_10). Colour input needs --channel: red, green or blue, or luma
(ITU-R BT.601: 0.299 R + 0.587 G + 0.114 B). 10/12/16-bit data are used at full depth. Frames
are streamed: a map holds its window, not the recording.

The map is computed from WINDOW consecutive frames starting at --start, comparing frames LAG
apart: S1 = mean |I_i - I_{i+m}| (grey levels), S2 = mean |I_i - I_{i+m}|/(I_i + I_{i+m} + q)
(for uneven illumination), S3 = S1/σ with σ each pixel's temporal standard deviation
(robust to ambient light). Higher values mean faster processes (more activity).

The field's other descriptors (docs/descriptors.md; as the reference toolbox BSLTL defines
them) are batch maps here: fujii (200 S2 at q = eps), gd (generalized differences, every pair
of frames), im (mean squared difference at LAG), contrast (σ/⟨I⟩), skewness, kurtosis, mhi
(motion history; needs --threshold), band_low, band_high and band_ratio (periodogram power
below/above --split, in Hz when --dt or the recording gives the frame interval). The noise
summary (docs/noise.md) is printed for those with a known floor: s1, s2, s3, fujii, im, gd.
`edgedsm thsp` draws one line's THSP.

With --timeline OUT_DIR it follows the activity against time instead (the paper's §3 reads
drying this way): a sliding window of N frames is sampled every --every frames, and
OUT_DIR/timeline.csv gets, per region and sample, the mean S1, S2, S3 and the region's τc
(frames and seconds), and the region mean of the streaming descriptor --estimator names or
the config's estimator.activity is (contrast, fujii, im, gd, band_low, band_high or band_ratio,
the bands split at --split, the ratio at q = 0); OUT_DIR/timeline.png plots them and
OUT_DIR/histogram.png shows the histogram of the S2 map (--histogram) against time. FRAMES may then also be a scene file
(or 'default'), simulated on the fly (--frames of them). Regions come from a daemon config
(-c), else the whole frame is one region named 'frame'.

Examples:
  edgedsm analyze frames.npy --estimator s1 --window 200 --lag 10 -o s1.npy --png
  edgedsm analyze frames/ --estimator s3 --window 50 --lag 4 -o s3.npy --png s3.png
  edgedsm analyze frames.npy --estimator gd --window 100 -o gd.npy --png
  edgedsm analyze frames.npy --estimator band_ratio --dt 0.02 --split 5 -o ratio.npy
  edgedsm analyze config/scenes/drying_demo.toml --frames 1200 --timeline out/ --window 100 --lag 2
  edgedsm analyze recording.npy --timeline out/ -c edgedsm.toml --dt 0.05
  edgedsm analyze drying/ --channel red --start 200 --window 200 --lag 5 --estimator s2 -o s2.npy
  edgedsm analyze run-12.tif --timeline out/ --window 200 --lag 5 --every 200
  edgedsm analyze run-12.tif --timeline out/ --window 200 --lag 1 --estimator fujii
  edgedsm analyze run-12.tif --timeline out/ --window 64 --estimator band_ratio --dt 0.02 --split 5
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from edgedsm.commands.common import add_progress_flag, progress
from edgedsm.commands.timeline_output import add_timeline_arguments, open_reader, run_timeline
from edgedsm.errors import EstimatorError
from edgedsm.estimators import ESTIMATORS, registry
from edgedsm.estimators.batch import s1
from edgedsm.estimators.descriptors import DESCRIPTORS, compute
from edgedsm.estimators.noise import from_datasheet
from edgedsm.estimators.noise_summary import model_summary
from edgedsm.frameio import CHANNELS, FrameReader
from edgedsm.imageio import save_map_png, write_atomic
from edgedsm.measurement import judge_window
from edgedsm.timeline import DESCRIPTORS as TIMELINE_DESCRIPTORS
from edgedsm.timeline import analysis_config

NAME = "analyze"
HELP = "compute an S1/S2/S3 activity map from frames"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("frames", metavar="FRAMES",
                        help=".npy, .tif (also BigTIFF, edgedsm recordings), a video, an image folder or "
                             "a pattern such as frames/%%05d.png")
    parser.add_argument("--channel", metavar="|".join(CHANNELS),
                        help="the channel of a colour input: red, green, blue, or luma (ITU-R BT.601 weights)")
    parser.add_argument("--estimator", choices=tuple(DESCRIPTORS), default=None, metavar="NAME",
                        help="s1: plain; s2: normalised by intensity; s3: normalised by σ (a map: default s1; "
                             "--timeline: default the config's estimator.activity, which the daemon judges, else "
                             "s2, the daemon's default); "
                             "or one of " + ", ".join(name for name in DESCRIPTORS if name not in ESTIMATORS)
                             + " (docs/descriptors.md)")
    parser.add_argument("--window", type=int, metavar="N", help="frames per map (default: all from --start)")
    parser.add_argument("--lag", type=int, default=1, metavar="m", help="time lag in frames (default 1)")
    parser.add_argument("--q", type=float, default=0.0,
                        help="s2 and band_ratio: added to the denominator (default 0)")
    parser.add_argument("--threshold", type=float, metavar="U",
                        help="mhi only: a change above U grey levels counts as motion")
    parser.add_argument("--split", type=float, metavar="F",
                        help="band_*: the frequency between the low and the high band, in Hz when the frame "
                             "interval is known (--dt, else the recording's), else in cycles per frame "
                             "(default half the Nyquist frequency)")
    parser.add_argument("--start", type=int, default=0, help="index of the first frame used (default 0)")
    parser.add_argument("-o", "--output", metavar="MAP.npy", help="float64 map as .npy (required without --timeline)")
    parser.add_argument("--png", nargs="?", const=True, metavar="PNG",
                        help="also write a colour-mapped picture (default: MAP.png beside the .npy)")
    parser.add_argument("--json", action="store_true", help="print the result as one JSON object")
    noise = parser.add_argument_group("the camera's noise (docs/noise.md; default: estimated from the frames)")
    noise.add_argument("--noise-gain", type=float, metavar="K",
                       help="system gain K in DN per electron (EMVA 1288 datasheet)")
    noise.add_argument("--dark-noise", type=float, default=0.0, metavar="E",
                       help="dark noise σ_d in electrons (datasheet; with --noise-gain)")
    noise.add_argument("--dark-mean", type=float, default=0.0, metavar="DN",
                       help="dark offset in grey levels (with --noise-gain)")
    add_timeline_arguments(parser)
    add_progress_flag(parser)


def run(args: argparse.Namespace) -> int:
    if args.timeline is not None:
        if args.estimator is not None and args.estimator not in (*ESTIMATORS, *TIMELINE_DESCRIPTORS):
            raise EstimatorError(f"--timeline follows s1, s2, s3, τc and the streaming descriptors "
                                 f"{', '.join(TIMELINE_DESCRIPTORS)}; {args.estimator} is a batch map only")
        return run_timeline(args)
    if args.output is None:
        raise EstimatorError("give -o MAP.npy (or --timeline OUT_DIR)")
    args.estimator = args.estimator or "s1"
    with open_reader(args) as reader:
        frames = read_window(reader, args)
        bits = reader.bits
        dt = args.dt if args.dt is not None else reader.dt  # the band_* frequencies' scale
    window = len(frames)
    descriptor = DESCRIPTORS[args.estimator]
    result = compute(args.estimator, frames, lag=args.lag, q=args.q, dt=dt, split=args.split,
                     threshold=args.threshold)
    lag_text = f", lag {args.lag}" if descriptor.uses_lag else ""
    if args.estimator.startswith("band_"):
        lag_text = f", frequencies in Hz (dt {dt:.4g} s)" if dt else ", frequencies in cycles per frame"
    output = Path(args.output)
    if output.suffix != ".npy":  # where np.save(output) has always written it
        output = output.with_name(output.name + ".npy")
    write_atomic(output, lambda file: np.save(file, result))  # whole or not at all
    message = (f"{args.estimator.upper()} from frames {args.start}..{args.start + window - 1}{lag_text}: "
               f"mean {result.mean():.4g}, min {result.min():.4g}, max {result.max():.4g} ({descriptor.unit})"
               f" -> {output}")
    png = None
    if args.png:
        png = output.with_suffix(".png") if args.png is True else Path(args.png)
        save_map_png(png, result, title=f"{args.estimator.upper()}  N={window}" + (
            f"  m={args.lag}" if descriptor.uses_lag else ""))
        message += f", {png}"
    if args.estimator in registry.with_floor():  # the maps with a floor (docs/noise.md), judged as the core judges
        noise_fields = _judged(frames, result, bits, args)
        noise_line = _noise_line(noise_fields)
    else:
        reason = (f"no noise floor is known for {args.estimator} yet (docs/noise.md covers "
                  f"{', '.join(registry.with_floor())})")
        noise_fields = {"noise_floor": None, "noise_floor_reason": reason, "above_noise": None,
                        "above_noise_spread": None, "above_noise_verdict": None, "signal": None,
                        "noise_model": None, "noise_model_error": None, "activity": None, "noise_view": None}
        noise_line = f"above noise: unknown ({reason})"
    if args.json:
        print(json.dumps({"estimator": args.estimator, "unit": descriptor.unit, "start": args.start,
                          "window": window, "lag": args.lag if descriptor.uses_lag else None, "dt": dt,
                          "shape": list(result.shape), "mean": float(result.mean()), "min": float(result.min()),
                          "max": float(result.max()), "output": str(output),
                          "png": str(png) if png is not None else None, **noise_fields}))
    else:
        print(message)
        print(noise_line)
    return 0


def _judged(frames: np.ndarray, result: np.ndarray, bits: int | None, args: argparse.Namespace) -> dict[str, object]:
    """The JSON keys of the map's noise summary: the map's mean as the measurement core judges it
    (:func:`edgedsm.measurement.judge_window`, the judge of the daemon and ``--timeline``) over the
    whole frame, or the daemon's patch at its centre with --noise-patch (``noise_view`` says which)."""
    values = {args.estimator: float(result.mean())}
    if "s1" not in values:  # the judge reads S1 beside every map (S3's floor is S1's)
        values["s1"] = float(s1(frames, args.lag).mean())
    config = analysis_config(len(frames), args.lag, args.q, activity=args.estimator)
    model = None if args.noise_gain is None else from_datasheet(args.noise_gain, args.dark_noise, args.dark_mean)
    reading, above, judgement = judge_window(config, frames, values, bits=bits, patch=args.noise_patch, model=model)
    signal = reading.signal
    assert signal is not None
    return {"noise_floor": None if above is None else above.floor, "activity": reading.activity,
            "above_noise": None if above is None else above.value,
            "above_noise_spread": None if above is None else above.spread,
            "above_noise_verdict": None if above is None else above.verdict,
            "signal": {"quality": signal.signal, "dark_fraction": signal.dark_fraction,
                       "saturated_fraction": signal.saturated_fraction, "speckle_contrast": signal.speckle_contrast},
            "noise_model": None if judgement.judge.model is None else model_summary(judgement.judge.model),
            "noise_model_error": None if judgement.judge.model is not None else (
                judgement.judge.keeper.error or signal.reason),
            "noise_view": reading.view}


def _noise_line(fields: dict) -> str:
    """One line: the activity above the camera's noise and the signal's quality."""
    signal = fields["signal"]
    if fields["above_noise"] is None:
        return f"above noise: unknown ({fields['noise_model_error']}); signal {signal['quality']}"
    model = fields["noise_model"]
    return (f"above noise: {fields['above_noise']:.4g} ± {fields['above_noise_spread']:.2g} (floor "
            f"{fields['noise_floor']:.4g}, {fields['above_noise_verdict']}; noise model from the "
            f"{model['source'] if model else '?'}; judged on the {fields['noise_view']}); signal {signal['quality']} "
            f"(dark {signal['dark_fraction']:.0%}, saturated {signal['saturated_fraction']:.0%})")


def read_window(reader: FrameReader, args: argparse.Namespace) -> np.ndarray:
    """Frames --start .. --start + --window - 1 (all from --start without --window), read one by
    one into one array: the only frames held."""
    total = reader.count
    if args.start < 0 or (total is not None and args.start >= total):
        raise EstimatorError(f"--start {args.start} is outside the {total} frames of {args.frames}")
    window = args.window if args.window is not None else (total - args.start if total is not None else None)
    if window is not None and (window < 2 or (total is not None and args.start + window > total)):
        raise EstimatorError(f"--window {window} from --start {args.start} does not fit the {total} frames")
    if window is None:  # a video of unknown length: all from --start, as asked
        stack = np.stack(list(progress(reader.frames(args.start), None, "read", args.progress)))
    else:
        stack = reader.window(args.start, window, lambda frames: progress(frames, window, "read", args.progress))
    if len(stack) < 2:
        raise EstimatorError(f"{args.frames}: {len(stack)} frame(s) from --start {args.start}; a map needs 2 or more")
    return stack
