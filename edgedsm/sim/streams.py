"""One seeded random stream per effect, so that effects never share random numbers.

Each effect has a fixed key; its stream is ``SeedSequence(seed, spawn_key=(key,))``. Adding or
removing an effect therefore leaves the numbers every other effect draws unchanged, and an
effect that is not simulated never creates its stream.
"""

from __future__ import annotations

import numpy as np

EFFECT_KEYS = {
    "surface": 0,        # initial delta-correlated phase, uniform on [0, 2π)
    "activity": 1,       # random-walk phase steps χ
    "phase_noise": 2,    # environmental phase noise θ
    "shot_noise": 3,     # Poisson photon noise of the laser signal
    "ambient_light": 4,  # Poisson photon noise of the ambient light
    "dark_current": 5,   # Poisson thermal electrons of the sensor
}


def effect_stream(seed: int, effect: str) -> np.random.Generator:
    """The random generator owned by ``effect`` for a scene seeded with ``seed``."""
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(seed, spawn_key=(EFFECT_KEYS[effect],))))
