"""The timeline's histogram in bounded memory (issue 38, part 3): the one map it needs, formed
alone from the engine's live sums, and its range's percentile taken in place, give the numbers
the whole-map path gave."""

from __future__ import annotations

import numpy as np
import pytest

from edgedsm.estimators import SlidingWindow
from edgedsm.timeline import DESCRIPTORS, histogram_map, timeline


def speckle(count: int, shape: tuple[int, int], seed: int = 3) -> np.ndarray:
    """Frames of an AR(1) complex Gaussian field's intensity (τc about 4 frames), 8-bit."""
    rng = np.random.default_rng(seed)
    r, s = np.exp(-1 / 8), np.sqrt(1 - np.exp(-1 / 4))
    field = rng.standard_normal((2, *shape))
    frames = []
    for _ in range(count):
        field = r * field + s * rng.standard_normal((2, *shape))
        frames.append(np.clip(20.0 * (field ** 2).sum(axis=0), 0, 255).astype(np.uint8))
    return np.stack(frames)


@pytest.mark.parametrize("mode", ["sliding", "tumbling"])
def test_histogram_map_is_the_engines_map(mode: str) -> None:
    frames = speckle(24, (16, 24))
    names = ("s1", "s2", "s3", *DESCRIPTORS)
    engine = SlidingWindow(frames.shape[1:], window=12, lag=2, estimators=names, mode=mode, dt=0.1)
    for frame in frames:
        engine.push(frame)
    whole = engine.maps(names)
    for name in names:
        alone = histogram_map(engine, name)
        assert alone.shape == frames.shape[1:] and alone.dtype == np.float64
        assert np.array_equal(alone, whole[name]), name
        assert np.ptp(alone) > 0, name  # a map, not zeros


def old_histograms(frames: np.ndarray, window: int, lag: int, every: int, name: str, bins: int
                   ) -> tuple[list[np.ndarray], np.ndarray]:
    """The histograms as the timeline formed them before: every map of the fused pass, the
    percentile of a copy."""
    mode = "tumbling" if every % window == 0 else "sliding"
    engine = SlidingWindow(frames.shape[1:], window=window, lag=lag, estimators=("s1", "s2", "s3"), mode=mode)
    found, span, edges = [], None, np.zeros(0)
    for index, frame in enumerate(frames):
        engine.push(frame)
        if not engine.ready or (index - (window - 1)) % every:
            continue
        values = engine.maps((name,))[name]
        if span is None:
            span = (0.0, 1.25 * float(np.percentile(values, 99.5)))
        density, edges = np.histogram(values, bins=bins, range=span, density=True)
        found.append(density)
    return found, edges


@pytest.mark.parametrize(("every", "name"), [(20, "s2"), (5, "s1"), (20, "s3")])
def test_the_timelines_histograms_are_unchanged(every: int, name: str) -> None:
    frames = speckle(70, (20, 30), seed=5)
    result = timeline(iter(frames), {"frame": np.ones(frames.shape[1:], bool)}, 20, 3, every, bins=16,
                      histogram_estimator=name, max_lag=8)
    expected, edges = old_histograms(frames, 20, 3, every, name, 16)
    assert len(result.histograms) == len(expected) == (3 if every == 20 else 11)
    for got, want in zip(result.histograms, expected, strict=True):
        assert np.array_equal(got, want)
    assert np.array_equal(result.histogram_edges, edges)
    assert max(float(h.max()) for h in expected) > 0
