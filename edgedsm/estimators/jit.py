"""numba's ``njit`` for the engine's kernels, cached on disk per variant and compiled once by
all the processes that want it at the same time.

numba keys its disk cache on a function's code and closure constants, not on the decorator's
options: the parallel and the serial variant of one factory's kernel shared one cache entry, and
whichever was compiled first ran for both (the daemon's warm-up compiles the serial region kernel
first on a small frame; at 4096×2168 that serial code then ran where the parallel one was asked
for, 4x slower). :func:`kernel_variant` names each variant, and so its cache file, after its
options.

Processes that start together (one daemon per camera at boot, the test suite's workers) want the
same kernels at the same moment, and numba's cache lets each of them compile every kernel: the
same seconds of CPU spent once per process, on the cores the measurement needs. :func:`compiled`
and :func:`kernel_variant` take a lock file beside the cache entry while they compile or load
(``flock``: released by the kernel if the process dies): the first process compiles and saves,
the others then load its entry from disk.

Importing this module does not import numba (the optional extra ``fast``); decorating does.
"""

from __future__ import annotations

import fcntl
import hashlib
import os
import time
from collections.abc import Callable
from typing import Any

#: How numba's OpenMP worker threads wait for the next parallel region. libgomp's default spins
#: for up to 300,000 iterations (milliseconds) after every region before it sleeps: a worker
#: then holds a core the daemon's other threads need between two pushes (evaluator, capture,
#: sinks): passive waiting sustained more frames and shorter evaluations in A/B trials of the
#: daemon at its capacity (docs/bench-design.md).
OMP_WAIT_POLICY = "PASSIVE"

#: Longest wait, in seconds, for another process's compile of the same kernel: a first compile
#: takes up to tens of seconds on a loaded 2-core machine; past this (a process stopped while
#: compiling) this process compiles on its own, as numba does without the lock.
COMPILE_WAIT_S = 180.0
#: Seconds between two tries of a lock another process holds.
LOCK_POLL_S = 0.05


def configure_threading() -> None:
    """Set the OpenMP wait policy (``OMP_WAIT_POLICY``) numba's threads will use, unless the
    environment sets one. The command line calls it first, for every command (``edgedsm run``
    and the benchmarks that measure the daemon alike): OpenMP reads it once, when numba first
    starts its threads."""
    os.environ.setdefault("OMP_WAIT_POLICY", OMP_WAIT_POLICY)


def kernel_variant(parallel: bool, **options: Any) -> Callable[[Callable[..., Any]], Any]:
    """``numba.njit(parallel=parallel, cache=True, nogil=True, **options)``, the compiled
    function's qualified name (which names its cache file) ending in ``.parallel`` or ``.serial``,
    compiled once across processes (:func:`compile_once`)."""

    def compile_variant(function: Callable[..., Any]) -> Any:
        function.__qualname__ = f"{function.__qualname__}.{'parallel' if parallel else 'serial'}"
        return compiled(parallel=parallel, nogil=True, **options)(function)

    return compile_variant


def compiled(**options: Any) -> Callable[[Callable[..., Any]], Any]:
    """``numba.njit(cache=True, **options)``, compiled once across processes (:func:`compile_once`);
    without numba (the optional extra ``fast``) the plain function, which callers then do not run
    (they take their NumPy path)."""
    try:
        import numba
    except ImportError:
        return lambda function: function

    def compile_function(function: Callable[..., Any]) -> Any:
        return compile_once(numba.njit(cache=True, **options)(function))

    return compile_function


def compile_once(dispatcher: Any) -> Any:
    """``dispatcher`` (a numba dispatcher with ``cache=True``), changed to compile or load each
    signature under a lock file beside its cache entry (:func:`lock_path`): a process that finds
    another compiling the same kernel waits (at most :data:`COMPILE_WAIT_S`), then loads the saved
    entry.

    The lock is taken inside numba's compiler lock (the order is the same in every thread, so a
    thread of the same process never holds the file while waiting for numba's lock). Without a
    writable cache folder the dispatcher compiles as numba does alone.
    """
    from numba.core.compiler_lock import global_compiler_lock

    path = lock_path(dispatcher)
    if path is None:
        return dispatcher
    compile_here = dispatcher.compile

    def compile_locked(signature: Any) -> Any:
        with global_compiler_lock:
            try:
                os.makedirs(os.path.dirname(path), exist_ok=True)  # numba makes it at its first save
                handle = os.open(path, os.O_CREAT | os.O_RDWR, 0o666)
            except OSError:  # a read-only cache folder: numba does not save there either
                return compile_here(signature)
            try:
                _lock(handle, COMPILE_WAIT_S)
                return compile_here(signature)
            finally:
                os.close(handle)  # releases the lock

    dispatcher.compile = compile_locked
    return dispatcher


def lock_path(dispatcher: Any) -> str | None:
    """The lock file of a cached dispatcher: in its cache folder, one per function and closure
    constants (the variants of one factory do not wait for each other); None without a disk cache."""
    folder = getattr(getattr(dispatcher, "_cache", None), "cache_path", None)
    if not folder:
        return None
    function = dispatcher.py_func
    constants = repr([cell.cell_contents for cell in function.__closure__ or ()])
    digest = hashlib.sha256(f"{function.__module__}.{function.__qualname__}:{constants}".encode()).hexdigest()[:16]
    return os.path.join(folder, f"{function.__qualname__}-{digest}.lock")


def _lock(handle: int, wait_s: float) -> bool:
    """Take the exclusive ``flock`` of ``handle``, waiting up to ``wait_s``; whether it was taken."""
    deadline = time.monotonic() + wait_s
    while True:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True
        except BlockingIOError:
            if time.monotonic() >= deadline:
                return False
            time.sleep(LOCK_POLL_S)
