"""'Simulate only what a scene calls for': absent effects draw nothing, effects never share streams."""

from __future__ import annotations

import numpy as np
import pytest

import edgedsm.sim.simulator as simulator_module
from edgedsm.sim import Simulator, scene_from_dict


def make(**tables):
    data = {"scene": {"size": 32, "frames": 8, "seed": 5}, "activity": {"tau_c": 10.0}}
    data.update(tables)
    return scene_from_dict(data)


def test_absent_effects_create_no_stream(monkeypatch):
    created = []
    real = simulator_module.effect_stream

    def spy(seed, effect):
        created.append(effect)
        return real(seed, effect)

    monkeypatch.setattr(simulator_module, "effect_stream", spy)
    sim = Simulator(make())
    list(sim.frames())
    assert set(created) == {"surface", "activity"}
    assert set(sim.rngs) == {"surface", "activity"}

    created.clear()
    full = make(phase_noise={"alpha": 0.2}, detector={}, ambient_light={"eta": 0.1},
                illumination={"kind": "gaussian", "omega": 20})
    list(Simulator(full).frames())
    assert set(created) == {"surface", "activity", "phase_noise", "shot_noise", "ambient_light"}


def test_zero_strength_effects_are_skipped():
    scene = make(phase_noise={"alpha": 0.0}, detector={"shot_noise": False}, ambient_light={"eta": 0.0},
                 illumination={"kind": "uniform"})
    assert scene.active_effects == ("surface", "activity", "detector")


def test_draw_counts_only_for_active_effects():
    # a stream's state tells how many numbers it gave out: unused streams stay at their seed state
    sim = Simulator(make(detector={}))
    fresh = {name: rng.bit_generator.state["state"]["state"] for name, rng in sim.rngs.items()}
    list(sim.frames())
    used = {name for name, rng in sim.rngs.items() if rng.bit_generator.state["state"]["state"] != fresh[name]}
    assert used == {"surface", "activity", "shot_noise"}


def test_switching_phase_noise_on_leaves_other_streams_unchanged():
    truth = Simulator(make())
    noisy = Simulator(make(phase_noise={"alpha": 0.05}))
    f_truth = [truth.next_intensity() for _ in range(6)]
    f_noisy = [noisy.next_intensity() for _ in range(6)]
    assert np.array_equal(f_truth[0], f_noisy[0])  # noise starts at the second frame
    for a, b in zip(f_truth[1:], f_noisy[1:], strict=True):
        assert not np.array_equal(a, b)
        # same surface, same activity walk: a small perturbation, not a new pattern
        assert np.corrcoef(a.ravel(), b.ravel())[0, 1] > 0.95
    assert truth.rngs["activity"].bit_generator.state == noisy.rngs["activity"].bit_generator.state


def test_switching_ambient_light_on_keeps_shot_noise_draws():
    det = {"n_max": 1000, "bits": 16, "quantization": False}
    truth = Simulator(make(detector=det))
    noisy = Simulator(make(detector=det, ambient_light={"eta": 0.05}))
    for _ in range(4):
        a, b = truth.next_frame(), noisy.next_frame()
        ok = b < 65535
        k = 65535 / (1000 + np.sqrt(1000))
        diff = (b - a)[ok] / k
        assert np.allclose(diff, np.rint(diff), atol=1e-3) and diff.min() >= 0
    assert truth.rngs["shot_noise"].bit_generator.state == noisy.rngs["shot_noise"].bit_generator.state


@pytest.mark.parametrize("extra", [{"illumination": {"kind": "gaussian", "omega": 20}},
                                   {"phase_noise": {"alpha": 0.3, "model": "ou", "tau_noise": 3}}])
def test_other_effects_do_not_change_surface_or_walk(extra):
    base, other = Simulator(make()), Simulator(make(**extra))
    for _ in range(5):
        base.next_intensity()
        other.next_intensity()
    for name in ("surface", "activity"):
        assert base.rngs[name].bit_generator.state == other.rngs[name].bit_generator.state
