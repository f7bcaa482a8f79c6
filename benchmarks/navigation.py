"""Navigation filter accuracy: the navigation service's estimate against truth, and the raw
measurement it filters, for 0.1, 1 and 10 m of position noise (velocity noise 1e-3 of it, per
s) over a mission.  Run: ``python -m benchmarks.navigation [DEPLOYMENT] [--orbits N]``.

The mission is flown in one process: the truth backend, every deputy's ``NavigationService``
(its own code, on a bus that only captures what it publishes) and its ``Controller``, flying on
the published estimate, as the services do."""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import dataclasses
import threading
from contextlib import nullcontext
from typing import Any

import numpy as np

from services.config import Deployment, load_deployment
from services.flight.control import Controller
from services.flight.navigation import NavigationService
from services.flight.runtime import ServiceContext
from services.interface import Message, decode, encode
from services.model import IN_PLANE, duration, exostate, navigation_state, on_grid, open_truth

NOISES = (0.1, 1.0, 10.0)
"""m, 1-sigma position noise per axis measured; the velocity noise is VELOCITY_RATIO of it."""
VELOCITY_RATIO = 1e-3
"""1/s: velocity noise (m/s) per metre of position noise, as a relative GPS solution gives
them (1 m and 1 mm/s)."""


class CaptureBus:
    """What a service needs of a Bus, in one process: subscriptions are ignored (the caller
    hands the service its messages) and each publication is encoded and decoded, as on the
    wire, then kept in ``published`` as (topic, Message)."""

    def __init__(self) -> None:
        self.published: list[tuple[str, Message]] = []
        self.counters: dict[str, int] = {}

    def subscribe(self, *_: Any, **__: Any) -> None:
        pass

    def publish(self, topic: str, schema: str, body: dict[str, Any], t: float) -> int:
        self.published.append((topic, decode(encode(schema, body, seq=0, t=t, src="nav"))))
        return 0

    def batch(self) -> nullcontext:
        return nullcontext()

    def declare_alive(self) -> None:
        pass


def _truth(sc: str, t: float, state: np.ndarray) -> Message:
    body = {"sc": sc, "r_N": state[:3], "v_N": state[3:], "sigma_BN": np.zeros(3)}
    return Message("truth", 1, 0, t, "environment", body)


def fly(dep: Deployment) -> dict[str, dict[str, np.ndarray]]:
    """Fly ``dep`` to its end with every deputy's NavigationService in the loop; per deputy:
    times ``t`` (K,), the true Hill state ``truth`` (K, 6), the measurement ``measured``
    (K, 6), the published estimate ``estimate`` (K, 6) and covariance ``cov`` (K, 6, 6)."""
    truth = open_truth(dep)
    navs, buses, ctrls = [], [], []
    for d in dep.deputy:
        bus = CaptureBus()
        ctx = ServiceContext(dep, "nav", f"nav-{d.name}", bus, threading.Event(), ".")  # type: ignore[arg-type]
        navs.append(NavigationService(ctx))
        buses.append(bus)
        ctrls.append(Controller(dep, d.name))
    out: dict[str, dict[str, list]] = {
        d.name: {k: [] for k in ("t", "truth", "measured", "estimate", "cov")} for d in dep.deputy
    }
    sigma = np.zeros((len(dep.deputy), 3))

    def sample(t: float, X: np.ndarray) -> None:
        v, _ = exostate(dep, t)
        for i, d in enumerate(dep.deputy):
            before = len(buses[i].published)
            navs[i].handle(_truth("chief", t, X[0]))
            navs[i].handle(_truth(d.name, t, X[i + 1]))
            if len(buses[i].published) == before:
                continue  # not on this deputy's navigation grid
            msg = buses[i].published[-1][1]
            x, z = (msg.body[k][list(IN_PLANE)] for k in ("x_hill", "z_hill"))
            outcome = ctrls[i].on_sample(t, x, v, msg.body["altitude"], z)
            if outcome.fsw:
                sigma[i] = [0.0, 0.0, ctrls[i].u]
            rec = out[d.name]
            rec["t"].append(t)
            rec["truth"].append(navigation_state(dep, d, X[0], X[i + 1]))
            rec["measured"].append(msg.body["z_hill"])  # the measurement as published
            rec["estimate"].append(msg.body["x_hill"])
            rec["cov"].append(msg.body["cov"])

    sample(0.0, truth.state)
    t_k, fsw, t_end = 0.0, dep.run.fsw_period, duration(dep)
    try:
        while t_k < t_end - 1e-6:
            samples, traj = truth.step(t_k, sigma)
            for k, t in enumerate(samples):
                if on_grid(float(t), dep.run.nav_period):
                    sample(float(t), traj[k])
            t_k += fsw
    finally:
        truth.close()
    return {name: {k: np.array(v) for k, v in rec.items()} for name, rec in out.items()}


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
    print("| noise (m, m/s) | deputy | raw position RMS (m) | filtered (m) | raw velocity RMS (m/s)"
          " | filtered (m/s) |\n|---|---|---|---|---|---|")  # fmt: skip
    for noise in NOISES:
        for name, rec in fly(with_noise(dep, noise, **extra)).items():
            raw = rms(rec["measured"] - rec["truth"])
            est = rms(rec["estimate"] - rec["truth"])
            print(f"| {noise:g}, {noise * VELOCITY_RATIO:g} | {name} | {raw[0]:.3g} | "
                  f"{est[0]:.3g} | {raw[1]:.3g} | {est[1]:.3g} |")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
