"""The time history of the speckle pattern (THSP) of one row or column, its co-occurrence matrix
(COM), and the COM's inertia moment (IM) and absolute value of the differences (AVD), as the
field's reference toolbox BSLTL computes them (thsp, coom, inertiamoment, avd; docs/descriptors.md).

FRAMES is anything `edgedsm analyze` reads (.npy, TIFF, an edgedsm recording, a video, an image
folder or pattern; --channel for colour). The THSP puts each pixel of the row (or column) in one
line of the picture and time along it: a still pixel draws a straight line, an active one a
grainy one. The COM counts each pixel's level k against its level at k+1: the more activity, the
wider the cloud around the diagonal; IM = Σ COM[i,j] (i-j)² / Σ COM (grey levels²) and
AVD = Σ COM[i,j] |i-j| / Σ COM (grey levels).

BSLTL's COM is 256 x 256 (8-bit levels): data of more bits are divided by 2^(bits-8) (their top 8
bits) for the COM, and IM and AVD are then in 8-bit grey levels; the THSP keeps full depth.

OUT_DIR gets thsp.png and com.png (colour-mapped pictures with labelled axes: the THSP's time in
frames across and position along the line in pixels down; the COM's grey level at t down and at
t+1 across, on a log scale), thsp.npy (float64, pixels x frames) and com.npy (int64 counts).

Examples:
  edgedsm thsp frames.npy --row 120 -o thsp-row120/
  edgedsm thsp seed.avi --column 64 --window 128 -o out/ --json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from edgedsm.commands.analyze import read_window
from edgedsm.commands.common import add_progress_flag
from edgedsm.commands.timeline_output import open_reader
from edgedsm.errors import DataError
from edgedsm.estimators.thsp import avd, coom, inertia_moment, thsp
from edgedsm.frameio import CHANNELS
from edgedsm.imageio import MapAxes, save_map_png

NAME = "thsp"
HELP = "THSP image, co-occurrence matrix, IM and AVD of one row or column (as BSLTL)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("frames", metavar="FRAMES",
                        help=".npy, .tif (also BigTIFF, edgedsm recordings), a video, an image folder or "
                             "a pattern such as frames/%%05d.png")
    line = parser.add_mutually_exclusive_group(required=True)
    line.add_argument("--row", type=int, metavar="R", help="the row of the THSP (0 = top)")
    line.add_argument("--column", type=int, metavar="C", help="the column of the THSP (0 = left)")
    parser.add_argument("--channel", metavar="|".join(CHANNELS),
                        help="the channel of a colour input: red, green, blue, or luma (ITU-R BT.601 weights)")
    parser.add_argument("--start", type=int, default=0, help="index of the first frame used (default 0)")
    parser.add_argument("--window", type=int, metavar="N", help="frames used (default: all from --start)")
    parser.add_argument("-o", "--output", metavar="OUT_DIR", required=True,
                        help="folder for thsp.png, com.png, thsp.npy and com.npy")
    parser.add_argument("--json", action="store_true", help="print the result as one JSON object")
    add_progress_flag(parser)


def run(args: argparse.Namespace) -> int:
    with open_reader(args) as reader:
        if reader.shape != (0, 0):  # known from the first frame's header: refuse before reading
            _check_line(args, reader.shape)
        frames = read_window(reader, args)
        _check_line(args, frames.shape[1:])
        bits = reader.bits
    what, index = ("row", args.row) if args.row is not None else ("column", args.column)
    image = thsp(frames, row=args.row, column=args.column)
    divisor = 2 ** (bits - 8) if bits is not None and bits > 8 else 1
    com = coom(np.floor(image / divisor) if divisor > 1 else image)
    moment, differences = inertia_moment(com), avd(com)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    np.save(out / "thsp.npy", image)
    np.save(out / "com.npy", com)
    window = len(frames)
    last = args.start + window - 1
    thsp_png = save_map_png(out / "thsp.png", image, title=f"THSP {what} {index}", unit="grey levels",
                            axes=thsp_axes(what, image.shape[0], args.start, last))
    com_png = save_map_png(out / "com.png", np.log1p(com), title=f"COM {what} {index}: log(1 + count)",
                           value_range=(0.0, max(float(np.log1p(com.max())), 1.0)), axes=com_axes(divisor))
    scale = f" (8-bit levels: {bits}-bit data / {divisor})" if divisor > 1 else ""
    if args.json:
        print(json.dumps({"line": what, "index": index, "start": args.start, "window": window,
                          "thsp_shape": list(image.shape), "im": moment, "avd": differences,
                          "com_divisor": divisor, "thsp_png": str(thsp_png), "com_png": str(com_png),
                          "thsp_npy": str(out / "thsp.npy"), "com_npy": str(out / "com.npy")}))
    else:
        print(f"THSP of {what} {index}, frames {args.start}..{args.start + window - 1}: {image.shape[0]} pixels"
              f" x {window} frames -> {thsp_png}, {com_png}")
        print(f"IM {moment:.6g} grey levels², AVD {differences:.6g} grey levels{scale}")
    return 0


def thsp_axes(what: str, pixels: int, first: int, last: int) -> MapAxes:
    """The THSP picture's axes: time along x (frame indices of the input), the line's pixels
    down y (0 = its left or top end)."""
    return MapAxes(x="time (frames)", y=f"position along the {what} (px)", x_range=(first, last),
                   y_range=(0, pixels - 1))


def com_axes(divisor: int) -> MapAxes:
    """The COM picture's axes: COM[a, b] counts level a at time k followed by level b at k + 1,
    so a runs down y and b along x; 8-bit levels (the data's divided by ``divisor``)."""
    levels = "grey level" if divisor == 1 else f"grey level / {divisor}"
    return MapAxes(x=f"{levels} at t+1", y=f"{levels} at t", x_range=(0, 255), y_range=(0, 255))


def _check_line(args: argparse.Namespace, shape: tuple[int, ...]) -> None:
    """The row or column must exist in the frames (bad data for this input: exit 65)."""
    height, width = shape
    what, index, size = (("row", args.row, height) if args.row is not None else ("column", args.column, width))
    if not 0 <= index < size:
        raise DataError(f"{args.frames}: {what} {index} is outside its {height}x{width} frames "
                        f"({what}s 0..{size - 1})")
