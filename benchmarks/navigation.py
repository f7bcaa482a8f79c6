"""Navigation filter accuracy: the navigation service's estimate against truth, and the raw
measurement it filters, for 0.1, 1 and 10 m of position noise (velocity noise 1e-3 of it, per
s) over a mission.  Run: ``python -m benchmarks.navigation [DEPLOYMENT] [--orbits N]``.

The mission is flown in one process (``services.flight.inprocess``): the truth backend, every
deputy's navigation (the component its navigation service runs) and its ``Controller``, flying
on the estimate, as the services do."""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import dataclasses
from typing import Any

import numpy as np

from services.config import Deployment, load_deployment
from services.flight.inprocess import run_in_process

NOISES = (0.1, 1.0, 10.0)
"""m, 1-sigma position noise per axis measured; the velocity noise is VELOCITY_RATIO of it."""
VELOCITY_RATIO = 1e-3
"""1/s: velocity noise (m/s) per metre of position noise, as a relative GPS solution gives
them (1 m and 1 mm/s)."""


def fly(dep: Deployment) -> dict[str, dict[str, np.ndarray]]:
    """Fly ``dep`` to its end in one process (``run_in_process``: the navigation component the
    services run, and the controller on its estimate); per deputy: times ``t`` (K,), the true
    Hill state ``truth`` (K, 6), the measurement ``measured`` (K, 6), the estimate
    ``estimate`` (K, 6) and covariance ``cov`` (K, 6, 6)."""
    names = {"t": "t", "truth": "x", "measured": "z", "estimate": "estimate", "cov": "cov"}
    return {
        deputy: {mine: rec[theirs] for mine, theirs in names.items()}
        for deputy, rec in run_in_process(dep).items()
    }


def rms(errors: np.ndarray) -> tuple[float, float]:
    """Position (m) and velocity (m/s) RMS of the 3-D error of Hill-state errors (K, 6)."""
    e2 = np.asarray(errors) ** 2
    return (float(np.sqrt(e2[:, :3].sum(1).mean())), float(np.sqrt(e2[:, 3:].sum(1).mean())))


def with_noise(dep: Deployment, position: float, **navigation: Any) -> Deployment:
    """``dep`` with every deputy's navigation noise set (velocity VELOCITY_RATIO of it)."""
    deputies = [
        dataclasses.replace(
            d,
            navigation=dataclasses.replace(
                d.navigation,
                position_noise=position,
                velocity_noise=position * VELOCITY_RATIO,
                **navigation,
            ),
        )
        for d in dep.deputy
    ]
    return dataclasses.replace(dep, deputy=deputies)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.navigation", description=__doc__)
    ap.add_argument("deployment", nargs="?", default="deployments/rendezvous.toml")
    ap.add_argument("--orbits", type=float, default=None, help="override run.orbits")
    ap.add_argument("--acceleration-noise", type=float, default=None, help="m/s^2")
    args = ap.parse_args(argv)
    dep = load_deployment(args.deployment)
    if args.orbits is not None:
        dep = dataclasses.replace(dep, run=dataclasses.replace(dep.run, orbits=args.orbits))
    extra = (
        {} if args.acceleration_noise is None else {"acceleration_noise": args.acceleration_noise}
    )
    print(
        "| noise (m, m/s) | deputy | raw position RMS (m) | filtered (m) | raw velocity RMS (m/s)"
        " | filtered (m/s) |\n|---|---|---|---|---|---|"
    )
    for noise in NOISES:
        for name, rec in fly(with_noise(dep, noise, **extra)).items():
            raw = rms(rec["measured"] - rec["truth"])
            est = rms(rec["estimate"] - rec["truth"])
            print(
                f"| {noise:g}, {noise * VELOCITY_RATIO:g} | {name} | {raw[0]:.3g} | "
                f"{est[0]:.3g} | {raw[1]:.3g} | {est[1]:.3g} |"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
