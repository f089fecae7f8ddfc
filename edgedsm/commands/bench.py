"""Benchmarks that put accuracy and cost side by side and print them as tables.

  edgedsm bench sim      simulator frames/s per effect, complex64 vs complex128, vs pyspeckle
  edgedsm bench engine   streaming estimator engine vs batch recompute, memory bandwidth bound
  edgedsm bench devices  camera drivers: frames/s and CPU per frame
  edgedsm bench e2e      the daemon end to end at 2048²: sustained frames/s, CPU, latency, memory
  edgedsm bench ambient  ambient-light correction of S2 against the ground truth (docs/ambient.md)
  edgedsm bench soak     faults in a loop against the daemon: alerts lost, laser-off delays, memory drift
  edgedsm bench accuracy what N, m, mode, estimator and smoothing cost and buy (docs/accuracy.md)
  edgedsm bench compression  lossless and lossy codecs: ratio, MB/s per core, map accuracy (docs/compression.md)
  edgedsm bench recording    what continuous [recording] costs the daemon's zero-drop rate (docs/bench-recording.md)
  edgedsm bench video    video decoders: PyAV against OpenCV, frames/s and exactness (docs/bench-video.md)
  edgedsm bench dashboard  the dashboard under N devices' traffic: CPU, broker load, page (docs/scaling.md)

Every benchmark prints a markdown table and can write it to a file (--output). The benchmarks are
the lab's (edgedsm_lab), which installs apart from edgedsm: `pip install -e ./lab` in the repository.
"""

from __future__ import annotations

import argparse
import importlib

from edgedsm.commands.common import LAB_INSTALL, LabNotInstalled, lab_installed

NAME = "bench"
HELP = "measure speed and accuracy (simulator, streaming engine, camera drivers, daemon end to end)"
#: Each suite and the module of the lab (edgedsm_lab, installed apart: lab/) that runs it.
SUITES = {name: f"edgedsm_lab.bench.{module}" for name, module in (
    ("sim", "sim"), ("engine", "engine"), ("devices", "devices"), ("e2e", "e2e_report"), ("ambient", "ambient"),
    ("soak", "soak"), ("accuracy", "accuracy_report"), ("compression", "compression"), ("recording", "recording"),
    ("light", "light"), ("video", "video"), ("dashboard", "dashboard"), ("kinetics", "kinetics"))}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    if not lab_installed():
        # any suite and its options parse, so that the run says how to install the lab (exit 69)
        parser.add_argument("suite", nargs=argparse.REMAINDER,
                            help=f"a suite of the lab, which is not installed: {LAB_INSTALL}")
        parser.set_defaults(bench_run=None)
        return
    sub = parser.add_subparsers(dest="suite", metavar="SUITE", required=True)
    for name, module_name in SUITES.items():
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name == module_name:
                continue
            raise
        suite = sub.add_parser(name, help=module.HELP, description=getattr(module, "DESCRIPTION", module.__doc__),
                               formatter_class=argparse.RawDescriptionHelpFormatter)
        module.add_arguments(suite)
        suite.set_defaults(bench_run=module.run)


def run(args: argparse.Namespace) -> int:
    if args.bench_run is None:
        raise LabNotInstalled(f"edgedsm bench needs the lab (edgedsm_lab): {LAB_INSTALL}")
    return int(args.bench_run(args) or 0)
