"""How a deputy's controller turns the linear model's input into an attitude command, and which
input acts on the plant when.  Every command goes through ddvi_core.models.drag_allocation,
scheduled on the deputy's altitude (its nav message), which makes the facet's drag linear in u
and the same at every altitude.  Control input u = sigma3, the relative MRP about the orbit
normal; sigma1 = sigma2 = 0."""

from __future__ import annotations

import bisect
import math

from ddvi_core.constants import R_EARTH
from ddvi_core.models import drag_allocation
from services.config import Deployment
from services.interface import command_topic


class Actuation:
    """The commands of deputy ``sc``: ``u``, the attitude command in force (sigma3);
    ``u_applied``, the linear-model input it realises; ``steps``, (T, u_applied) of every
    flight-software step so far, and ``at_limit``, whether each step's input was out of reach
    (the attitude at its limit)."""

    def __init__(self, dep: Deployment, sc: str) -> None:
        self.fsw = dep.run.fsw_period
        self.limit = dep.deputy_named(sc).attitude_limit
        # a command issued at T acts from the environment's first step at or after T + this
        # (docs/design.md, "Time"): the flight software knows its actuation link's latency
        self.delay = dep.link_latency(f"ctrl-{sc}", "environment", command_topic(sc))
        self.normal_angle = math.radians(dep.spacecraft.normal_angle)
        self.h_model = dep.chief.a - R_EARTH
        self.scale_height = dep.atmosphere.scale_height
        self.u = 0.0
        self.u_applied = 0.0
        self.steps: list[tuple[float, float]] = []
        self.at_limit: list[bool] = []

    def density_ratio(self, altitude: float) -> float:
        """rho(h) / rho(h_0) of the nominal exponential atmosphere: how much more drag the
        facet makes at altitude h (m) than the linear model's reference altitude h_0 (the
        chief's initial orbit).  The pair decays about 1.4 km in 15 orbits, and the drag, hence
        B, rises about 19% with it."""
        return math.exp(-(altitude - self.h_model) / self.scale_height)

    def allocate(self, t: float, u: float, altitude: float) -> float:
        """The attitude command sigma3 for the linear-model input u of the step at t, the
        deputy at ``altitude`` (m); recorded with the input it realises."""
        # schedule on the measured altitude: the drag the linear model's u stands for is the
        # same at every altitude, so the learner sees one B (and the LQR its design B)
        ratio = self.density_ratio(altitude)
        self.u, u_area = drag_allocation(u / ratio, self.normal_angle, self.limit)
        self.u_applied = u_area * ratio
        self.steps.append((t, self.u_applied))
        # the allocation's own rounding moves an input within reach by about 1e-17
        self.at_limit.append(abs(u_area - u / ratio) > 1e-9)
        return self.u

    def fraction_at_limit(self, start: float, end: float) -> float:
        """The fraction of the flight-software steps from ``start`` to ``end`` (s, both
        included) whose input was out of reach: the attitude held at its limit, the drag not
        following the input (0 if no step).  Only the steps the control law flew count: a step
        in the safe attitude (stale navigation) computes no input."""
        lo = bisect.bisect_left(self.steps, start - 1e-6, key=lambda step: step[0])
        hi = bisect.bisect_right(self.steps, end + 1e-6, key=lambda step: step[0])
        return sum(self.at_limit[lo:hi]) / (hi - lo) if hi > lo else 0.0

    def first_acting_step(self, t: float) -> float:
        """The first flight-software step (s) at which a command issued at t acts on the plant:
        the data of a learner that starts at t begin there."""
        return math.ceil((t + self.delay) / self.fsw - 1e-9) * self.fsw

    def input_at(self, t: float) -> float:
        """The linear-model input this controller had in force at time t: that of its newest
        step at or before t (a delayed sample is collected after later steps have run)."""
        k = bisect.bisect_right(self.steps, t + 1e-6, key=lambda step: step[0])
        return self.steps[k - 1][1] if k else 0.0

    def input_acting(self, t: float) -> float:
        """The linear-model input acting on the plant from t to the next sample: the
        environment takes commands at each flight-software boundary T_k, the newest issued by
        T_k - actuation delay (none yet: the zero command).  With no delay, ``input_at(t)``.
        Exact for a fixed delay; with jitter the environment may apply a command a step sooner
        than this assumes, and a command lost on its link leaves the previous one acting."""
        t_k = math.floor(t / self.fsw + 1e-9) * self.fsw
        issued = math.floor((t_k - self.delay) / self.fsw + 1e-9) * self.fsw
        return self.input_at(issued) if issued > -1e-6 else 0.0
