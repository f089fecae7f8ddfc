"""A command's own peak memory: run it as the grandchild of a small interpreter and read wait4.

A child's ``ru_maxrss`` includes the RSS of the process it was forked from (the high-water mark
survives exec), so a benchmark's or a test runner's own size would be counted in every command it
starts. Started by :data:`SPAWNER` (a fresh ``python -I`` of a few MiB), the command's peak is its
own. Used by the benchmarks (``timeline_archive``) and the hostile-file tests.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: Runs argv[2:] and writes "<exit code> <peak RSS in KiB>" of it to the file argv[1].
SPAWNER = """
import os, sys
pid = os.posix_spawn(sys.argv[2], sys.argv[2:], os.environ)
_, status, usage = os.wait4(pid, 0)
with open(sys.argv[1], "w") as out:
    out.write(f"{os.waitstatus_to_exitcode(status)} {usage.ru_maxrss}")
"""


@dataclass
class Measured:
    """How a command ended: its exit code (negative for a signal), its output, its own peak RSS
    (bytes) and its wall time (s)."""

    code: int
    out: str
    err: str
    rss: int
    seconds: float


def measure(command: list[str], timeout: float = 60.0, **popen: Any) -> Measured:
    """Run ``command`` (its first item an absolute path) under :data:`SPAWNER`; at ``timeout``
    seconds it is killed with its session and ``TimeoutError`` raised. ``popen``: Popen's
    ``env``, ``cwd``."""
    started = time.perf_counter()
    with tempfile.TemporaryDirectory() as folder:
        report, out_path, err_path = Path(folder) / "report", Path(folder) / "stdout", Path(folder) / "stderr"
        with open(out_path, "wb") as out, open(err_path, "wb") as err:
            process = subprocess.Popen([sys.executable, "-I", "-c", SPAWNER, str(report), *command],
                                       stdin=subprocess.DEVNULL, stdout=out, stderr=err,
                                       start_new_session=True, **popen)
            try:
                process.wait(timeout)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()
                raise TimeoutError(f"{command} did not end within {timeout:g} s") from None
        seconds = time.perf_counter() - started
        code, rss_kib = report.read_text().split()
        return Measured(int(code), out_path.read_text(errors="replace"), err_path.read_text(errors="replace"),
                        int(rss_kib) * 1024, seconds)  # Linux: ru_maxrss in KiB
