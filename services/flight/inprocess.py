"""The mission stepped in one process with no bus: the same truth, navigation and controller
code as the services, called directly.  It is the baseline the distributed run is measured
against (benchmarks) and a quick way to study the learner on truth data."""

from __future__ import annotations

import time

import numpy as np

from services.config import Deployment
from services.flight.control import Controller
from services.flight.relative_navigation import RelativeNavigation
from services.model import (
    IN_PLANE,
    duration,
    exostate,
    on_grid,
    open_truth,
    panel_schedule,
)


def run_in_process(dep: Deployment, timing: dict[str, float] | None = None) -> dict[str, dict]:
    """Run ``dep`` to the end; per deputy, at its navigation samples: times ``t`` (K,), the
    truth ``x`` (K, 6) in navigation's frame, the measurement ``z`` (K, 6), the estimate
    ``estimate`` (K, 6) and its covariance ``cov`` (K, 6, 6), the command in force ``u``
    (K,); the ``controller`` object (final gains, phase) and its learning ``log`` lines.
    Each deputy's navigation is its navigation service's (``RelativeNavigation``: the same
    noise draws, bias faults and filter).

    ``timing``, if given, gets the wall seconds of each service's share: ``environment``
    (truth, exostate), ``nav-<deputy>`` (states, bias, noise, filter), ``ctrl-<deputy>``
    (controller and learning), and ``steps``, the flight-software steps."""
    clock = time.perf_counter
    spent = dict.fromkeys(
        ["environment", *(f"{p}-{d.name}" for d in dep.deputy for p in ("nav", "ctrl"))], 0.0
    )
    run = dep.run
    fsw, t_end = run.fsw_period, duration(dep)
    truth = open_truth(dep)
    ctrls = [Controller(dep, d.name) for d in dep.deputy]
    navigations = [RelativeNavigation(dep, d) for d in dep.deputy]
    series = ("t", "x", "z", "estimate", "cov", "u")
    out = {d.name: {**{k: [] for k in series}, "log": []} for d in dep.deputy}
    sigma = np.zeros((len(ctrls), 3))

    def sample(t: float, X: np.ndarray) -> None:
        t0 = clock()
        v, _ = exostate(dep, t)
        spent["environment"] += clock() - t0
        for i, (d, c) in enumerate(zip(dep.deputy, ctrls, strict=True)):
            if not on_grid(t, navigations[i].period):
                continue
            t0 = clock()
            nav = navigations[i].measure(t, X[0], X[i + 1])
            t1 = clock()
            plane = list(IN_PLANE)  # the controller's state: x, y and their rates
            outcome = c.on_sample(t, nav.x[plane], v, nav.altitude, nav.z[plane])
            spent[f"nav-{d.name}"] += t1 - t0
            spent[f"ctrl-{d.name}"] += clock() - t1
            if outcome.learn_log is not None:
                out[d.name]["log"].append(outcome.learn_log)
            if outcome.fsw:
                sigma[i] = [0.0, 0.0, c.u]
            rec = out[d.name]
            rec["t"].append(t)
            rec["x"].append(nav.truth)
            rec["z"].append(nav.z)
            rec["estimate"].append(nav.x)
            rec["cov"].append(nav.cov)
            rec["u"].append(c.u)

    sample(0.0, truth.state)
    t_k = 0.0
    names = [d.name for d in dep.deputy]
    # panel faults as the environment applies them
    panels = panel_schedule(dep)
    steps = 0
    try:
        while t_k < t_end - 1e-6:
            while panels and panels[0][0] <= t_k + 1e-6:
                _, sc, factor, angle = panels.pop(0)
                truth.set_panel(names.index(sc), factor, angle)
            t0 = clock()
            samples, traj = truth.step(t_k, sigma)
            spent["environment"] += clock() - t0
            for k, t in enumerate(samples):
                sample(float(t), traj[k])
            t_k += fsw
            steps += 1
    finally:
        truth.close()
    if timing is not None:
        timing.update(spent, steps=steps)
    for d, c in zip(dep.deputy, ctrls, strict=True):
        rec = out[d.name]
        rec.update({k: np.array(rec[k]) for k in series})
        rec["controller"] = c
    return out
