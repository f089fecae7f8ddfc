"""The per-pixel validation table of docs/tau_c.md ("Per-pixel validation") on the simulator.

48² scenes with a uniform τc, 8-bit detector (N_max = 1000, shot noise), without noise and with
white phase noise α = 0.5 plus ambient light η = 0.2 (seed 3, one run of 1600 frames per
(τc, noise), its first N frames used); K = max(20, 2τc), at most N-2.

    PYTHONPATH=. python scripts/tau_pixel_table.py
"""

from __future__ import annotations

import numpy as np

from edgedsm.estimators import tau_c_bounds
from edgedsm.estimators.correlation_time import (
    ABOVE,
    MEASURED,
    covariances,
    fit_correlations,
    normalise,
    tau_lags,
)
from edgedsm.sim import Simulator, scene_from_dict

SIZE, FRAMES, SEED = 48, 1600, 3
ROWS = {2: (100, 200, 400, 800, 1600), 5: (100, 200, 400, 800, 1600), 10: (100, 200, 400, 800, 1600),
        20: (200, 400, 800, 1600), 50: (800, 1000, 1600)}


def frames_of(tau: float, noisy: bool) -> np.ndarray:
    scene = {"scene": {"size": SIZE, "frames": FRAMES, "seed": SEED}, "activity": {"tau_c": float(tau)},
             "detector": {"n_max": 1000, "bits": 8}}
    if noisy:
        scene["phase_noise"] = {"alpha": 0.5, "tau_noise": 1.0, "model": "white"}
        scene["ambient_light"] = {"eta": 0.2}
    return np.stack(list(Simulator(scene_from_dict(scene)).frames()))


def uncorrected_median(stack: np.ndarray, top: int) -> float:
    """Median of the per-pixel fits before the median-unbiasing ("> K" pixels count as K)."""
    lags = tau_lags(top)
    cov, var = covariances(stack, top)
    corr, _ = normalise(cov.reshape(lags.size, -1), var.reshape(-1))
    tau, _, status = fit_correlations(corr, stack.shape[0], lags)
    return float(np.median(np.where(status == ABOVE, float(top), tau)))


def main() -> None:
    print("| τc | noise | N | K | N/τc | region | pixel median, uncorrected | pixel median | measured |")
    print("|---:|---|---:|---:|---:|---:|---:|---:|---:|")
    for tau, windows in ROWS.items():
        for noisy in (False, True):
            frames = frames_of(tau, noisy)
            for n in windows:
                stack = frames[:n]
                top = min(max(20, 2 * tau), n - 2)
                region = tau_c_bounds(stack, top, mask=np.ones((SIZE, SIZE), bool))
                pixels = tau_c_bounds(stack, top)
                raw, corrected = uncorrected_median(stack, top), float(np.median(pixels.tau))
                name = "α=0.5, η=0.2" if noisy else "none"
                print(f"| {tau} | {name} | {n} | {top} | {n // tau} | {region.tau:.1f} "
                      f"| {raw:.1f} ({raw / tau - 1:+.0%}) | {corrected:.1f} ({corrected / tau - 1:+.0%}) "
                      f"| {(pixels.status == MEASURED).mean():.0%} |", flush=True)


if __name__ == "__main__":
    main()
