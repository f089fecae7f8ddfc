"""numba's ``njit`` for kernels that factories build as closures, cached on disk per variant.

numba keys its disk cache on a function's code and closure constants, not on the decorator's
options: the parallel and the serial variant of one factory's kernel shared one cache entry, and
whichever was compiled first ran for both (the daemon's warm-up compiles the serial region kernel
first on a small frame; at 4096×2168 that serial code then ran where the parallel one was asked
for, 4x slower). :func:`kernel_variant` names each variant, and so its cache file, after its
options.

Importing this module does not import numba (the optional extra ``fast``); decorating does.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from typing import Any

#: How numba's OpenMP worker threads wait for the next parallel region. libgomp's default spins
#: for up to 300,000 iterations (milliseconds) after every region before it sleeps: a worker
#: then holds a core the daemon's other threads need between two pushes (evaluator, capture,
#: sinks): passive waiting sustained more frames and shorter evaluations in A/B trials of the
#: daemon at its capacity (docs/bench-design.md).
OMP_WAIT_POLICY = "PASSIVE"


def configure_threading() -> None:
    """Set the OpenMP wait policy (``OMP_WAIT_POLICY``) numba's threads will use, unless the
    environment sets one. The command line calls it first, for every command (``edgedsm run``
    and the benchmarks that measure the daemon alike): OpenMP reads it once, when numba first
    starts its threads."""
    os.environ.setdefault("OMP_WAIT_POLICY", OMP_WAIT_POLICY)


def kernel_variant(parallel: bool, **options: Any) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """``numba.njit(parallel=parallel, cache=True, nogil=True, **options)``, the compiled
    function's qualified name (which names its cache file) ending in ``.parallel`` or ``.serial``."""
    import numba

    def compile_variant(function: Callable[..., Any]) -> Callable[..., Any]:
        function.__qualname__ = f"{function.__qualname__}.{'parallel' if parallel else 'serial'}"
        return numba.njit(parallel=parallel, cache=True, nogil=True, **options)(function)

    return compile_variant
