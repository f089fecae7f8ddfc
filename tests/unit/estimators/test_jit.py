"""Kernels compiled once across processes (edgedsm.estimators.jit.compile_once): processes that
want the same kernel at the same moment (a daemon per camera at boot, the suite's workers) share
one compile through numba's disk cache instead of each compiling it."""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.skipif(importlib.util.find_spec("numba") is None, reason="numba (extra 'fast') absent")

REPO = Path(__file__).resolve().parents[3]

KERNEL_MODULE = textwrap.dedent('''
    import numpy as np
    from edgedsm.estimators.jit import {decorator}

    def build(scale):
        @{decorator}({options})
        def kernel(values, out):
            for i in range(values.size):  # enough code that compiling takes a while
                x = values[i] * scale
                out[i] = np.sqrt(abs(x)) + np.log1p(abs(x)) + np.sin(x) * np.cos(x) + np.tanh(x)
        return kernel
''')

PROCESS = textwrap.dedent('''
    import json, os, sys, time
    from pathlib import Path
    import numpy as np
    sys.path.insert(0, sys.argv[1])
    import kernels
    kernel = kernels.build(float(sys.argv[3]))
    folder = Path(sys.argv[1])
    (folder / f"ready-{sys.argv[2]}").touch()
    deadline = time.monotonic() + 60
    while len(list(folder.glob("ready-*"))) < 2 and time.monotonic() < deadline:  # start together
        time.sleep(0.001)
    kernel(np.arange(5.0), np.empty(5))
    print(json.dumps({"misses": sum(kernel.stats.cache_misses.values()),
                      "hits": sum(kernel.stats.cache_hits.values())}))
''')


def run_two_processes(folder: Path, decorator: str, options: str, scales: tuple[str, str]) -> list[dict[str, int]]:
    """Two processes that build the kernel and call it at the same moment: numba's cache counts."""
    (folder / "kernels.py").write_text(KERNEL_MODULE.format(decorator=decorator, options=options))
    (folder / "process.py").write_text(PROCESS)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(folder / "cache"), "PYTHONPATH": str(REPO)}
    started = [subprocess.Popen([sys.executable, str(folder / "process.py"), str(folder), str(i), scales[i]],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
               for i in range(2)]
    counts = []
    for process in started:
        out, err = process.communicate(timeout=120)
        assert process.returncode == 0, err[-2000:]
        counts.append(json.loads(out.strip().splitlines()[-1]))
    return counts


@pytest.mark.parametrize(("decorator", "options"), [("compiled", "nogil=True"), ("kernel_variant", "False")])
def test_two_processes_wanting_one_kernel_compile_it_once(tmp_path: Path, decorator: str, options: str) -> None:
    counts = run_two_processes(tmp_path, decorator, options, ("2.0", "2.0"))
    assert sorted(c["misses"] for c in counts) == [0, 1], counts  # one compiled it ...
    assert sorted(c["hits"] for c in counts) == [0, 1], counts  # ... the other loaded it


def test_variants_of_one_factory_do_not_wait_for_each_other(tmp_path: Path) -> None:
    """Other closure constants, another kernel: each process compiles its own, under its own lock."""
    counts = run_two_processes(tmp_path, "compiled", "nogil=True", ("2.0", "3.0"))
    assert [c["misses"] for c in counts] == [1, 1], counts
    locks = sorted(p.name for p in (tmp_path / "cache").rglob("*.lock"))
    assert len(locks) == 2 and all(name.startswith("build.<locals>.kernel-") for name in locks), locks


STUCK_HOLDER = textwrap.dedent('''
    import fcntl, json, os, sys, time
    import numpy as np
    sys.path.insert(0, sys.argv[1])
    import kernels
    from edgedsm.estimators import jit
    kernel = kernels.build(2.0)
    path = jit.lock_path(kernel)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    holder = os.open(path, os.O_CREAT | os.O_RDWR)
    fcntl.flock(holder, fcntl.LOCK_EX)  # another open file: to flock, another process holding it
    jit.COMPILE_WAIT_S = 0.5
    started = time.monotonic()
    out = np.empty(3)
    kernel(np.array([0.0, 1.0, -2.0]), out)
    print(json.dumps({"waited_s": time.monotonic() - started, "misses": sum(kernel.stats.cache_misses.values()),
                      "out": out.tolist()}))
''')


def test_a_holder_that_never_finishes_delays_the_compile_only_up_to_the_wait_limit(tmp_path: Path) -> None:
    """A process stopped while compiling must not stop the others: past COMPILE_WAIT_S they
    compile on their own (as numba does without the lock), with the same result."""
    (tmp_path / "kernels.py").write_text(KERNEL_MODULE.format(decorator="compiled", options="nogil=True"))
    (tmp_path / "holder.py").write_text(STUCK_HOLDER)
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cache"), "PYTHONPATH": str(REPO)}
    done = subprocess.run([sys.executable, str(tmp_path / "holder.py"), str(tmp_path)], capture_output=True,
                          text=True, env=env, timeout=120, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["waited_s"] >= 0.5 and result["misses"] == 1, result
    x = np.array([0.0, 2.0, -4.0])  # the inputs times the scale 2.0
    expected = np.sqrt(abs(x)) + np.log1p(abs(x)) + np.sin(x) * np.cos(x) + np.tanh(x)
    assert np.allclose(result["out"], expected, rtol=1e-12, atol=0.0), result
