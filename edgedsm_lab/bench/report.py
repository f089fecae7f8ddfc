"""What every benchmark report shares: the machine it ran on, markdown tables, the file under docs/.

A benchmark builds its report with :class:`Report`; each line is printed as it comes (so a long
run shows progress) and kept for the markdown file::

    from edgedsm_lab.bench.report import Report, add_output_argument, load_average

    def add_arguments(parser):
        add_output_argument(parser, "docs/bench-foo.md")       # -o/--output FILE.md

    def run(args):
        load = load_average()                                   # before the timing
        ...measure...
        report = Report("Foo benchmark")                        # '# Foo benchmark' and a blank line
        report.line(report.machine("edgedsm bench foo", "numba", load=load) + " More set-up text.")
        report.line()
        report.table(["case", "frames/s"], [["a", "12.5"], ["b", "3.1"]])  # 1st column left, rest right
        report.line()
        if args.output:
            report.save(args.output)                            # parent directories created
        return 0

``machine()`` returns the one-sentence header: the command, the date, the CPU model and
architecture, the logical CPUs, the Python/numpy/module versions and the load average.
``table(header, rows, align="llr...")`` writes a markdown table (``l``/``r`` per column).
``markdown_table`` gives the same lines without a report, ``write_markdown`` writes any lines.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np


def cpu_model() -> str:
    """The processor's model name (from /proc/cpuinfo on Linux)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown CPU"


def versions(*modules: str) -> str:
    """'Python x, numpy y, <module> z, ...'; numba also says its thread count and how its
    OpenMP threads wait (``OMP_WAIT_POLICY``, edgedsm.estimators.jit)."""
    parts = [f"Python {platform.python_version()}", f"numpy {np.__version__}"]
    for module in modules:
        try:
            imported = __import__(module)
        except ImportError:
            parts.append(f"{module} (not installed)")
            continue
        text = f"{module} {imported.__version__}"
        if module == "numba":
            policy = os.environ.get("OMP_WAIT_POLICY", "unset")
            text += f" ({imported.config.NUMBA_NUM_THREADS} threads, OpenMP wait policy {policy})"
        parts.append(text)
    return ", ".join(parts)


def load_average() -> float | None:
    """The 1-minute load average, or None where the system does not tell."""
    try:
        return os.getloadavg()[0]
    except OSError:
        return None


@dataclass(frozen=True)
class CpuSample:
    """CPU time so far, in seconds: the whole machine's busy time (all CPUs, including time the
    hypervisor stole) and this process's own (with its children that have been waited for)."""

    busy_s: float
    own_s: float
    wall_s: float


def cpu_sample() -> CpuSample | None:
    """Now, or None where /proc/stat does not tell (not Linux)."""
    try:
        fields = Path("/proc/stat").read_text().splitlines()[0].split()
    except (OSError, IndexError):
        return None
    if fields[:1] != ["cpu"] or len(fields) < 9:
        return None
    # user nice system idle iowait irq softirq steal (guest time is inside user already)
    user, nice, system, _idle, _iowait, irq, softirq, steal = (int(value) for value in fields[1:9])
    times = os.times()
    return CpuSample(busy_s=(user + nice + system + irq + softirq + steal) / os.sysconf("SC_CLK_TCK"),
                     own_s=times.user + times.system + times.children_user + times.children_system,
                     wall_s=time.monotonic())


def others_share(before: CpuSample | None, after: CpuSample | None) -> float | None:
    """The share (0–1) of the machine's CPU time between two samples that went to other work:
    other processes and the hypervisor's steal. Unlike the load average, this is blind to
    what ran before the first sample (e.g. the previous benchmark's decaying load)."""
    if before is None or after is None or after.wall_s <= before.wall_s:
        return None
    others = (after.busy_s - before.busy_s) - (after.own_s - before.own_s)
    return min(1.0, max(0.0, others / ((after.wall_s - before.wall_s) * (os.cpu_count() or 1))))


#: Above this share of the machine's CPU time taken by other work, a run counts as shared.
SHARED_ABOVE = 0.05


def machine_use(others: float | None, load: float | None) -> str:
    """The sentences after the machine header that say whether other work ran during the run:
    from ``others`` (:func:`others_share`), else from the load average before the run."""
    quiet = others < SHARED_ABOVE if others is not None else load is not None and load < 1.0
    took = "" if others is None else f" Other work took {others:.1%} of the machine's CPU time during the run."
    return took + (" Little else ran on the machine during the run; still, only the ratios measured in this "
                   "one run are meant to carry over to other machines." if quiet else
                   " The machine is shared: other work ran on its cores during the run, so every rate is "
                   "noisy and only the ratios measured in this one run mean much.")


def format_load(load: float | None) -> str:
    """The load average with two decimals, or "unknown"."""
    return "unknown" if load is None else f"{load:.2f}"


def machine_header(command: str, *modules: str, load: float | None = None,
                   load_after: float | None = None) -> str:
    """'`command` on DATE: CPU (arch), N logical CPUs; Python x, numpy y, ...; load average ...'.

    ``load`` is the load average before the run, ``load_after`` (optional) the one after it:
    other work on the machine slows the figures at random, so the reader should see it.
    """
    text = (f"`{command}` on {datetime.date.today().isoformat()}: {cpu_model()} "
            f"({platform.machine()}), {os.cpu_count()} logical CPUs; {versions(*modules)}")
    if load is not None or load_after is not None:
        text += f"; load average {format_load(load)} before the run"
        if load_after is not None:
            text += f", {format_load(load_after)} after it"
    return text + "."


def markdown_table(header: Sequence[str], rows: Iterable[Sequence[object]],
                   align: str | None = None) -> list[str]:
    """A markdown table as lines; ``align`` is one 'l' or 'r' per column (default: the first
    column left, the others right). Cells are written with ``str``; '|' inside a cell is escaped."""
    align = align or "l" + "r" * (len(header) - 1)
    if len(align) != len(header) or set(align) - {"l", "r"}:
        raise ValueError(f"align needs one 'l' or 'r' per column ({len(header)}), got {align!r}")

    def row_line(cells: Sequence[object]) -> str:
        if len(cells) != len(header):
            raise ValueError(f"a row has {len(cells)} cells for {len(header)} columns: {cells!r}")
        return "| " + " | ".join(str(cell).replace("|", "\\|") for cell in cells) + " |"

    rule = "|" + "|".join("---" if a == "l" else "---:" for a in align) + "|"
    return [row_line(header), rule, *(row_line(row) for row in rows)]


def write_markdown(path: str | Path, lines: list[str]) -> Path:
    """Write the report's lines (parent directories created) and say so on stderr."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines).rstrip() + "\n", encoding="utf-8")
    print(f"wrote {path}", file=sys.stderr)
    return path


def add_output_argument(parser: argparse.ArgumentParser, suggested: str, extra: str = "") -> None:
    """The ``-o/--output FILE.md`` option every benchmark has (``suggested``: its file under docs/)."""
    parser.add_argument("-o", "--output", metavar="FILE.md",
                        help=f"also write the report as markdown{extra} (the project keeps it as "
                             f"{suggested})")


class Report:
    """A markdown report whose lines are printed as they are added (see the module docstring)."""

    def __init__(self, title: str, echo: Callable[[str], None] | None = None) -> None:
        self.lines: list[str] = []
        self._echo = echo if echo is not None else (lambda text: print(text, flush=True))
        self.line(f"# {title}")
        self.line()

    def line(self, text: str = "") -> None:
        """Add one line (printed now)."""
        self.lines.append(text)
        self._echo(text)

    def extend(self, lines: Iterable[str]) -> None:
        for text in lines:
            self.line(text)

    def table(self, header: Sequence[str], rows: Iterable[Sequence[object]],
              align: str | None = None) -> None:
        """Add a markdown table (see :func:`markdown_table`)."""
        self.extend(markdown_table(header, rows, align))

    @staticmethod
    def machine(command: str, *modules: str, load: float | None = None,
                load_after: float | None = None) -> str:
        """The machine header sentence (see :func:`machine_header`)."""
        return machine_header(command, *modules, load=load, load_after=load_after)

    def save(self, path: str | Path) -> Path:
        """Write the report to ``path`` (parent directories created); returns the path."""
        return write_markdown(path, self.lines)
