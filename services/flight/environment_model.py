"""The environment as a component: the truth propagated one flight-software step at a time with
each deputy's command in force, the panel faults, the craft's attitudes and the exostate, with
no bus, no wall clock and no I/O, so that the environment service and the one-process executor
fly the same code.

Inputs:  ``commands.deliver(sc, for_t, sigma, now, expected)``: a command its link delivered;
         ``panel_from_ground(fault, src)``: a panel fault the ground sent; the deployment's
         scheduled [[fault]] panels, at their times.
Outputs: ``step(t_k)``: the samples' times (K,) and every craft's state (K, 1 + N, 6) over the
         step, with what to say (the panel faults applied or refused); ``attitudes(traj)``:
         sigma_BN (K, 1 + N, 3); ``exostate(t)``; the counters.
"""

from __future__ import annotations

import math

import numpy as np

from ddvi_core.orbit import dcm_to_mrp, hill_frame, mrp_to_dcm
from services.config import Deployment
from services.flight.streams import FaultQueue
from services.model import Truth, describe_panel, exostate, panel_schedule

Panel = tuple[str, float | None, float | None]
"""A panel fault: (deputy, area factor, normal angle (deg)); None leaves that part as it was."""


class CommandsInForce:
    """Each deputy's commanded relative MRP in force (``sigma`` (N, 3)), clipped to its
    attitude limit: a delivered command is put in force unless it is not newer than the one in
    force (a replay: counted stale) or for a step not clocked yet (counted bad).

    Parameters
    ----------
    dep : the deployment (its deputies and their attitude limits).
    counters : the environment's counters; it keeps its own among them.
    """

    def __init__(self, dep: Deployment, counters: dict[str, int]) -> None:
        self.deputies = [d.name for d in dep.deputy]
        self.counters = counters
        counters.update(
            late_commands=0,
            missing_commands=0,
            stale_commands=0,
            clipped_commands=0,
            bad_commands=0,
        )
        # clipped to the attitude limit, per deputy too: the report says whose (outcome)
        counters.update({f"clipped_commands.{sc}": 0 for sc in self.deputies})
        self.limits = np.array([d.attitude_limit for d in dep.deputy])
        self.sigma = np.zeros((len(self.deputies), 3))
        self.latest_for_t = dict.fromkeys(self.deputies, -math.inf)  # step of the one in force

    def deliver(
        self, sc: str, for_t: float, sigma: list[float], now: float, expected: float
    ) -> None:
        """The command of deputy ``sc`` for step ``for_t``, delivered during the step at
        ``now`` whose newest command should be for step ``expected``."""
        counters = self.counters
        if sc not in self.latest_for_t or for_t > now + 1e-6:
            # not a deputy of the run, or for a step this environment has not clocked yet: no
            # controller can have sent it (a stolen credential's, which would otherwise make
            # every genuine command stale)
            counters["bad_commands"] += 1
            return
        if for_t <= self.latest_for_t[sc]:
            counters["stale_commands"] += 1  # not newer than the one in force: a replay
            return
        if for_t < expected - 1e-6:
            counters["late_commands"] += 1
        i = self.deputies.index(sc)
        clipped = np.clip(sigma, -self.limits[i], self.limits[i])
        if np.any(clipped != sigma):
            counters["clipped_commands"] += 1
            counters[f"clipped_commands.{sc}"] += 1
        self.sigma[i] = clipped
        self.latest_for_t[sc] = for_t

    def count_missing(self, expected: dict[str, float]) -> None:
        """The step's commands taken: count each deputy whose command for its ``expected``
        step (s, by deputy; negative: none due yet) is not in force (lost, or not sent)."""
        self.counters["missing_commands"] += sum(
            expected[sc] >= 0 and self.latest_for_t[sc] < expected[sc] - 1e-6
            for sc in self.deputies
        )


class EnvironmentModel:
    """Propagates the truth one flight-software step at a time with the commands in force.

    Parameters
    ----------
    dep : the deployment.
    truth : the truth model every craft is propagated with (``services.model.open_truth``).
    """

    def __init__(self, dep: Deployment, truth: Truth) -> None:
        self.dep, self.truth = dep, truth
        self.deputies = [d.name for d in dep.deputy]
        self.names = ["chief", *self.deputies]
        self.counters: dict[str, int] = {"steps": 0, "panel_faults": 0, "bad_faults": 0}
        self.commands = CommandsInForce(dep, self.counters)
        self.panel_faults: FaultQueue[Panel] = FaultQueue(
            [(t, (sc, factor, angle)) for t, sc, factor, angle in panel_schedule(dep)]
        )

    def panel_from_ground(self, fault: Panel, src: str) -> None:
        """A panel fault the ground's service ``src`` sent: applied at the next step."""
        self.panel_faults.from_ground(fault, src)

    def step(self, t_k: float) -> tuple[np.ndarray, np.ndarray, list[tuple[str, str]]]:
        """Apply the panel faults due at t_k, then propagate one flight-software step with the
        commands in force: the sample times (K,), every craft's state (K, 1 + N, 6), and what
        to say, (level, text) pairs.  Raises ``services.model.ReentryError`` if a craft
        re-enters."""
        said = self.apply_panel_faults(t_k)
        samples, traj = self.truth.step(t_k, self.commands.sigma)
        self.counters["steps"] += 1
        return samples, traj, said

    def exostate(self, t: float) -> tuple[np.ndarray, float]:
        """The exostate v and the reference's phase at t (``services.model.exostate``)."""
        return exostate(self.dep, t)

    def attitudes(self, traj: np.ndarray) -> np.ndarray:
        """sigma_BN (K, 1 + N, 3) of states (K, 1 + N, 6): the chief Hill-pointing, each
        deputy Hill-pointing composed with its command in force (one batched call a step)."""
        k, n = traj.shape[0], len(self.names)
        HN = hill_frame(traj[..., :3].reshape(-1, 3), traj[..., 3:].reshape(-1, 3))
        HN = HN.reshape(k, n, 3, 3)
        BN = HN.copy()
        if self.deputies:
            BN[:, 1:] = mrp_to_dcm(self.commands.sigma) @ HN[:, 1:]
        return dcm_to_mrp(BN.reshape(-1, 3, 3)).reshape(k, n, 3)

    def apply_panel_faults(self, t_k: float) -> list[tuple[str, str]]:
        """Set the panels of the faults due at t_k, in time order (the ground's first)."""
        said = []
        for fault in sorted(self.panel_faults.pop_due(t_k), key=lambda f: f.t):
            sc, factor, angle = fault.value
            try:
                self.truth.set_panel(self.deputies.index(sc), factor, angle)
            except (ValueError, RuntimeError) as exc:
                self.counters["bad_faults"] += 1
                said.append(("warning", f"fault panel {sc}: refused ({exc})"))
                continue
            self.counters["panel_faults"] += 1
            said.append(
                (
                    "warning",
                    f"fault panel {sc}: {describe_panel(factor, angle)} "
                    f"from t = {t_k:.0f} s ({fault.origin})",
                )
            )
        return said
