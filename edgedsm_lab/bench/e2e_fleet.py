"""Cameras per PC: K daemons side by side on one machine, each on its own paced replay.

Each daemon is a child process running one paced trial of :mod:`edgedsm_lab.bench.e2e` (the real
``Pipeline``, the default configuration, its own ``MqttSink`` to one shared mosquitto) with
``NUMBA_NUM_THREADS`` kernel threads; all start together. Per K and thread count the table
gives each camera's processed rate, drops and CPU (ms per frame and share of one core), so the
rule of ``docs/scaling.md`` can be read off: how many cameras of a given size and rate one
machine carries with zero drops.

Example:
  python -m edgedsm_lab.bench.e2e_fleet --size 1024x1024 --rate 60 --instances 1,2,4 --threads 1,2
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from edgedsm.estimators.jit import configure_threading
from edgedsm_lab.bench.e2e_trial import make_recording, parse_size
from edgedsm_lab.bench.report import Report, cpu_sample, load_average, machine_use, others_share


def child(args: argparse.Namespace) -> int:
    """One daemon's trial, printed as a JSON line."""
    from edgedsm_lab.bench.e2e_trial import daemon_config, quiet_daemon_logs, run_trial

    shape = args.size
    config = daemon_config(Path(args.recording), args.port, Path(args.state), args.rate, 8, shape)
    with quiet_daemon_logs():
        trial = run_trial("fleet", config, rate=args.rate, seconds=args.seconds)
    print(json.dumps({"fps": trial.fps, "drops": trial.drops, "cpu_ms": trial.cpu_ms,
                      "cpu_share": trial.cpu_s / trial.seconds, "delivered_fps": trial.delivered_fps,
                      "alert_p99": trial.latency["alert"][1]}))
    return 0


def run_fleet(count: int, threads: int, args: argparse.Namespace, recording: Path, port: int,
              workdir: Path) -> list[dict[str, float]]:
    import edgedsm

    root = str(Path(edgedsm.__file__).resolve().parents[1])
    env = {**os.environ, "NUMBA_NUM_THREADS": str(threads),
           "PYTHONPATH": os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")]))}
    size = f"{args.size[1]}x{args.size[0]}"
    children = [subprocess.Popen(
        [sys.executable, "-m", "edgedsm_lab.bench.e2e_fleet", "--child", "--size", size, "--rate", str(args.rate),
         "--seconds", str(args.seconds), "--recording", str(recording), "--port", str(port),
         "--state", str(workdir / f"state-{count}-{threads}-{k}")],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for k in range(count)]
    results = []
    for process in children:
        out, err = process.communicate(timeout=args.seconds + 300)
        if process.returncode != 0:
            raise RuntimeError(f"a daemon of the fleet failed:\n{err[-2000:]}")
        results.append(json.loads(out.strip().splitlines()[-1]))
    return results


def main(argv: list[str] | None = None) -> int:
    configure_threading()  # each child stands for a daemon: the command line's threading settings
    parser = argparse.ArgumentParser(prog="python -m edgedsm_lab.bench.e2e_fleet", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--size", type=parse_size, default=(1024, 1024), metavar="WxH")
    parser.add_argument("--rate", type=float, default=60.0, help="frames/s of each camera (default 60)")
    parser.add_argument("--instances", default="1,2,4", help="daemon counts (default 1,2,4)")
    parser.add_argument("--threads", default="1,2", help="numba threads per daemon (default 1,2)")
    parser.add_argument("--seconds", type=float, default=15.0, help="seconds per trial after the window filled")
    parser.add_argument("-o", "--output", metavar="FILE.md", help="also write the table as markdown")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--recording", help=argparse.SUPPRESS)
    parser.add_argument("--port", type=int, help=argparse.SUPPRESS)
    parser.add_argument("--state", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        return child(args)
    from edgedsm.localbroker import LocalBroker

    load = load_average()
    start = cpu_sample()
    rows = []
    with tempfile.TemporaryDirectory(prefix="edgedsm-fleet-") as tmp, LocalBroker() as broker:
        recording = make_recording(Path(tmp) / "r.npy", args.size)
        for threads in (int(t) for t in args.threads.split(",")):
            for count in (int(k) for k in args.instances.split(",")):
                print(f"{count} daemon(s), {threads} numba thread(s) each ...", file=sys.stderr, flush=True)
                results = run_fleet(count, threads, args, recording, broker.port, Path(tmp))
                rows.append([str(count), str(threads), f"{args.rate:g}",
                             " / ".join(f"{r['fps']:.1f}" for r in results),
                             f"**{sum(int(r['drops']) for r in results)}**",
                             f"{max(r['cpu_ms'] for r in results):.1f}",
                             f"{100 * sum(r['cpu_share'] for r in results):.0f} %",
                             f"{max(r['alert_p99'] for r in results):.2f}"])
    report = Report("Cameras per PC")
    report.line(report.machine(f"python -m edgedsm_lab.bench.e2e_fleet --size {args.size[1]}x{args.size[0]} "
                               f"--rate {args.rate:g}", "numba", load=load, load_after=load_average()) +
                machine_use(others_share(start, cpu_sample()), load))
    report.line()
    report.table(["daemons", "numba threads each", "frames/s asked each", "processed frames/s each",
                  "drops (all)", "CPU ms/frame (worst)", "CPU all daemons (2 cores = 200 %)",
                  "frame → alert p99 s (worst)"], rows)
    if args.output:
        report.save(args.output)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
