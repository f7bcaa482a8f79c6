"""Cost of the truth propagation as the environment uses it.

One ``propagate`` call per 60 s flight-software step with navigation samples every 10 s, J2 and
drag on, Hill-referenced attitudes, for a 40-orbit mission (3,621 calls), with the chief and 1
deputy, and with the chief and 16 deputies.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_truth.py
"""

from __future__ import annotations

import math
import time

import numpy as np

from ddvi_core.constants import MU_EARTH
from ddvi_core.orbit import hill_to_rv, mrp_to_dcm
from ddvi_core.truth import propagate, rendezvous_initial_states


def mission_states(n_deputies: int) -> np.ndarray:
    x0 = rendezvous_initial_states()
    if n_deputies == 1:
        return x0
    rng = np.random.default_rng(0)
    xh = rng.normal(size=(n_deputies, 6)) * [200.0, 3e4, 100.0, 0.1, 0.4, 0.1]
    rd, vd = hill_to_rv(x0[0, :3], x0[0, 3:], xh)
    return np.vstack([x0[:1], np.hstack([rd, vd])])


def run(n_deputies: int, orbits: float = 40.0) -> tuple[float, int]:
    x = mission_states(n_deputies)
    sigma = np.zeros((n_deputies + 1, 3))
    sigma[1:, 2] = np.linspace(-0.2, 0.2, n_deputies)
    att = mrp_to_dcm(sigma)
    t_end = orbits * 2 * math.pi * math.sqrt(6678.136e3**3 / MU_EARTH)
    t, calls = 0.0, 0
    start = time.perf_counter()
    while t < t_end:
        t1 = t + 60.0
        samples = propagate(
            x, t, t1, att, attitude_frame="hill", t_eval=np.arange(t, t1 + 1e-9, 10.0)
        )
        x, t, calls = samples[-1], t1, calls + 1
    return time.perf_counter() - start, calls


def main() -> None:
    for n in (1, 16):
        wall, calls = run(n)
        print(
            f"chief + {n:2d} deputies: {calls} calls, {wall:.2f} s per 40-orbit mission, "
            f"{wall / calls * 1e3:.3f} ms per 60 s call"
        )


if __name__ == "__main__":
    main()
