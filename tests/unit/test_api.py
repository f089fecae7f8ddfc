"""The package's Python API (edgedsm/__init__.py): every public name imports and is the object its
module defines, `import edgedsm` alone stays cheap for the command line (no numba, numpy or
OpenCV), and the batch estimators' docstring examples hold."""

from __future__ import annotations

import doctest
import importlib
import subprocess
import sys

import numpy as np
import pytest

import edgedsm
from edgedsm.estimators import batch

NAMES = ("s1", "s2", "s3", "temporal_sigma", "tau_c", "SlidingWindow", "open_frames", "load_scene", "simulate",
         "fujii", "gd", "im", "contrast", "skewness", "kurtosis", "mhi", "band_low", "band_high", "band_ratio",
         "save_map_png")


@pytest.mark.parametrize("name", NAMES)
def test_each_public_name_is_its_modules_object(name: str) -> None:
    assert name in edgedsm.__all__ and name in dir(edgedsm)
    value = getattr(edgedsm, name)
    module = importlib.import_module(value.__module__)
    assert getattr(module, name) is value and value.__module__.startswith("edgedsm.")


def test_every_name_of_all_resolves_and_star_import_gives_them() -> None:
    namespace: dict[str, object] = {}
    exec("from edgedsm import *", namespace)
    assert set(edgedsm.__all__) <= set(namespace) and namespace["__version__"] == edgedsm.__version__
    with pytest.raises(AttributeError, match="module 'edgedsm' has no attribute 'nothing_here'"):
        edgedsm.nothing_here  # noqa: B018


def test_import_edgedsm_loads_no_numerics() -> None:
    code = ("import sys, edgedsm; heavy = [m for m in ('numba', 'numpy', 'cv2', 'edgedsm.estimators') "
            "if m in sys.modules]; print(heavy); edgedsm.s2; print('numpy' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    assert done.stdout.split("\n")[:2] == ["[]", "True"]  # nothing until a name is used, then its module


def test_the_api_computes_what_its_modules_compute() -> None:
    frames = np.random.default_rng(2).integers(0, 256, (40, 6, 7), dtype=np.uint8)
    np.testing.assert_array_equal(edgedsm.s2(frames, 3), batch.s2(frames, 3))
    assert edgedsm.tau_c(frames).shape == (6, 7) and edgedsm.fujii(frames).shape == (6, 7)


def test_the_batch_estimators_docstring_examples_hold() -> None:
    failed, attempted = doctest.testmod(batch, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert (failed, attempted) == (0, 7)
    for function in (batch.s1, batch.s2, batch.s3):
        text = function.__doc__
        assert all(word in text for word in ("(N, H, W)", "(H, W) float64", "lag: m, in frames"))
