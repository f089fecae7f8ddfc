"""Darkening, exposure steps, ambient-light steps and dark current: simulated only when a scene
asks, each from its own stream."""

from __future__ import annotations

import math

import numpy as np
import pytest

import edgedsm.sim.simulator as simulator_module
from edgedsm.errors import ConfigError
from edgedsm.sim import Simulator, scene_from_dict


def make(**tables):
    data = {"scene": {"size": 32, "frames": 12, "seed": 5}, "activity": {"tau_c": 10.0},
            "detector": {"n_max": 4000, "bits": 12}}
    data.update(tables)
    return scene_from_dict(data)


def test_absent_light_effects_cost_nothing_and_change_nothing(monkeypatch):
    created = []
    real = simulator_module.effect_stream

    def spy(seed, effect):
        created.append(effect)
        return real(seed, effect)

    monkeypatch.setattr(simulator_module, "effect_stream", spy)
    plain = make()
    assert plain.active_effects == ("surface", "activity", "detector", "shot_noise")
    frames = list(Simulator(plain).frames())
    assert "dark_current" not in created
    # a zero dark current and an exposure of 1 are the plain scene, frame for frame
    same = make(detector={"n_max": 4000, "bits": 12, "dark_current": 0.0}, exposure_steps=[{"frame": 0, "factor": 1.0}])
    assert all(np.array_equal(a, b) for a, b in zip(frames, Simulator(same).frames(), strict=True))


def test_dark_current_draws_from_its_own_stream():
    scene = make(detector={"n_max": 4000, "bits": 12, "dark_current": 50.0})
    assert "dark_current" in scene.active_effects
    plain, dark = Simulator(make()), Simulator(scene)
    a, b = np.stack(list(plain.frames())).astype(float), np.stack(list(dark.frames())).astype(float)
    assert plain.rngs["shot_noise"].bit_generator.state == dark.rngs["shot_noise"].bit_generator.state
    scale = 4095 / (4000 + math.sqrt(4000))  # grey levels per photon (or electron)
    assert (b - a).mean() == pytest.approx(50.0 * scale, rel=0.05)
    assert (b - a).var() == pytest.approx(50.0 * scale**2 + 1 / 6, rel=0.1)  # Poisson, plus rounding twice


def test_darkening_and_exposure_steps_scale_the_light():
    scene = make(darkening={"law": "linear", "start": 2, "duration": 8, "final_factor": 0.2},
                 exposure_steps=[{"frame": 6, "factor": 0.5}])
    assert [round(scene.light_level(i), 3) for i in (0, 2, 6, 10, 11)] == [1.0, 1.0, 0.5 * 0.6, 0.5 * 0.2, 0.1]
    truth = np.array([frame.mean() for frame in Simulator(make(detector={"n_max": 4000, "bits": 12,
                                                                         "shot_noise": False})).frames()])
    noiseless = make(detector={"n_max": 4000, "bits": 12, "shot_noise": False},
                     darkening={"law": "linear", "start": 2, "duration": 8, "final_factor": 0.2},
                     exposure_steps=[{"frame": 6, "factor": 0.5}])
    levels = np.array([frame.mean() for frame in Simulator(noiseless).frames()]) / truth
    assert np.allclose(levels, [noiseless.light_level(i) for i in range(12)], atol=0.01)


def test_ambient_light_steps_add_their_photons_from_the_frame_on_with_their_poisson_noise():
    steps = {"eta": 0.0, "steps": [{"frame": 4, "eta": 0.05}, {"frame": 8, "eta": 0.02}]}
    scene = make(ambient_light=steps)
    assert "ambient_light" in scene.active_effects
    assert [scene.ambient_light.eta_at(i) for i in (0, 3, 4, 7, 8, 11)] == [0.0, 0.0, 0.05, 0.05, 0.02, 0.02]
    plain, lit = Simulator(make()), Simulator(scene)
    a, b = np.stack(list(plain.frames())).astype(float), np.stack(list(lit.frames())).astype(float)
    scale = 4095 / (4000 + math.sqrt(4000))  # grey levels per photon
    unclipped = b < 4095  # a saturated pixel loses part of what was added
    added = [(b - a)[i][unclipped[i]] for i in range(12)]
    assert all(np.all(frame == 0.0) for frame in added[:4])  # η = 0 draws nothing: the plain scene's frames
    for frames, eta in ((added[4:8], 0.05), (added[8:], 0.02)):
        values = np.concatenate(frames)
        assert values.mean() == pytest.approx(eta * 4000 * scale, rel=0.02)
        assert values.var() == pytest.approx(eta * 4000 * scale**2 + 1 / 6, rel=0.1)  # Poisson(η·N_max)
    # the process's own streams are untouched by the ambient light's
    assert lit.rngs["shot_noise"].bit_generator.state == plain.rngs["shot_noise"].bit_generator.state


@pytest.mark.parametrize("tables, message", [
    ({"ambient_light": {"eta": 0.1, "steps": [{"frame": 5, "eta": 0.2}, {"frame": 5, "eta": 0.3}]}},
     "increasing order"),
    ({"exposure_steps": [{"frame": 5, "factor": 2.0}, {"frame": 3, "factor": 1.0}]}, "increasing order"),
    ({"darkening": {"duration": 10, "final_factor": 1.5}}, "final_factor"),
    ({"darkening": {"duration": 10, "final_factor": 0.5}, "detector": None}, "need a \\[detector\\]"),
    ({"detector": {"dark_current": -1.0}}, "dark_current"),
])
def test_scene_refuses_bad_light_tables(tables, message):
    data = {"scene": {"size": 32, "frames": 4}, "activity": {"tau_c": 10.0}, "detector": {}}
    data.update(tables)
    data = {key: value for key, value in data.items() if value is not None}
    with pytest.raises(ConfigError, match=message):
        scene_from_dict(data)
