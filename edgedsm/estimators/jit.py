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

from collections.abc import Callable
from typing import Any


def kernel_variant(parallel: bool, **options: Any) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """``numba.njit(parallel=parallel, cache=True, nogil=True, **options)``, the compiled
    function's qualified name (which names its cache file) ending in ``.parallel`` or ``.serial``."""
    import numba

    def compile_variant(function: Callable[..., Any]) -> Callable[..., Any]:
        function.__qualname__ = f"{function.__qualname__}.{'parallel' if parallel else 'serial'}"
        return numba.njit(parallel=parallel, cache=True, nogil=True, **options)(function)

    return compile_variant
