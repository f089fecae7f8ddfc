"""Thread priorities: work that can wait yields the cores to the engine's kernel threads.

On a machine with few cores a parallel engine pass waits for its slowest kernel thread, so a
thread that shares a core with one of them at the same priority stretches every pass it
overlaps (docs/bench-design.md has the figures). A lower priority moves such work into the
moments the kernel threads idle, and costs it nothing when the cores are free. Linux sets a
nice value per thread; elsewhere, or where the system refuses, the thread keeps its priority.
"""

from __future__ import annotations

import logging
import os
import threading

log = logging.getLogger(__name__)


def lower_priority(nice: int) -> None:
    """Make the calling thread ``nice`` steps nicer than the process (at most 19)."""
    try:
        thread = threading.get_native_id()
        os.setpriority(os.PRIO_PROCESS, thread, min(19, os.getpriority(os.PRIO_PROCESS, os.getpid()) + nice))
    except (OSError, AttributeError):  # not Linux, or not allowed: the default priority
        log.debug("thread %s keeps the default priority", threading.current_thread().name)
