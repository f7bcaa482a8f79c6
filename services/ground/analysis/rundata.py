"""The monitor's memory of a run: what it learned from the bus, one decoded message at a time.

``RunData`` keeps, per spacecraft, the time series the report needs (truth, navigation,
commands, gains, controller status) in compact ``array('d')`` buffers, plus every service's
counters as its stats say them, each believed only when it can be true
(``services.ground.analysis.claims``: against what arrived from the service and what is possible),
and the notable events (faults, warnings, errors).

The truth Hill state is ``ddvi_core.orbit.rv_to_hill`` of deputy vs chief at the same sample
time, with the chief's gravitational acceleration (two-body + J2 when the deployment has J2)
as ``a_c`` so that zdot includes the rotation of the chief's orbit plane; ``hill_states``
computes it for all samples at once (same formula, checked against rv_to_hill in the tests).
"""

from __future__ import annotations

from array import array
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ddvi_core.orbit import hill_frame, rv_to_hill
from ddvi_core.truth import acceleration
from services.config import Deployment, Deputy
from services.ground.analysis.claims import Claims
from services.ground.analysis.refusals import Refusals
from services.interface import Message
from services.model import duration, orbit_period

FloatArray = NDArray[np.float64]

MAX_EVENTS = 200  # warnings/errors/faults kept for the report


class Series:
    """Samples of a fixed width keyed by time; a repeated time overwrites (duplicates)."""

    def __init__(self, width: int) -> None:
        self.width = width
        self.t = array("d")
        self.values = array("d")
        self.index: dict[float, int] = {}

    def add(self, t: float, values: Any) -> None:
        """Append the sample (``width`` values) at ``t``, or overwrite the one there."""
        row = [float(v) for v in values]
        if len(row) != self.width:
            raise ValueError(f"expected {self.width} values, got {len(row)}")
        k = self.index.get(t)
        if k is not None:
            self.values[k * self.width : (k + 1) * self.width] = array("d", row)
            return
        self.index[t] = len(self.t)
        self.t.append(t)
        self.values.extend(row)

    def __len__(self) -> int:
        return len(self.t)

    def last(self) -> tuple[float, FloatArray] | None:
        """The sample added last: (t, values (width,)); None when there is none."""
        if not self.t:
            return None
        return self.t[-1], np.asarray(self.values[-self.width :])

    def arrays(self) -> tuple[FloatArray, FloatArray]:
        """(t (N,), values (N, width)) sorted by time."""
        t = np.frombuffer(self.t, dtype=np.float64).copy()
        v = np.frombuffer(self.values, dtype=np.float64).reshape(-1, self.width).copy()
        order = np.argsort(t, kind="stable")
        return t[order], v[order]


@dataclass
class GainRecord:
    """A ``gains`` message: K (1, 4) and L (1, 5) as lists, and where they came from."""

    t: float
    K: list[list[float]]
    L: list[list[float]]
    source: str
    iteration: int
    converged: bool


@dataclass
class StatusRecord:
    """A controller's ``status`` message body at time t."""

    t: float
    body: dict[str, Any]


@dataclass
class CraftData:
    """Everything received about one spacecraft (chief or deputy)."""

    truth: Series = field(default_factory=lambda: Series(6))  # r_N, v_N
    nav: Series = field(default_factory=lambda: Series(7))  # x_hill, valid
    cmd: Series = field(default_factory=lambda: Series(3))  # sigma, keyed by for_t
    gains: list[GainRecord] = field(default_factory=list)
    status: list[StatusRecord] = field(default_factory=list)


class RunData:
    """What the monitor learned from the bus, fed one decoded message at a time."""

    def __init__(
        self, dep: Deployment, run: str, dropped: Callable[[str], int] | None = None
    ) -> None:
        self.dep = dep
        self.run = run
        self.period = orbit_period(dep)
        self.duration = duration(dep)
        self.craft: dict[str, CraftData] = {}
        self.sim_t = 0.0  # latest clock time (or any message's t before the first clock)
        self.clock_seen = False
        self.final_seen = False
        self.final_t: float | None = None  # time of the final clock
        # every service's stats, each believed only when possible; ``dropped``: what the
        # ground's rate budget dropped unread from a publisher so far
        # (services.ground.analysis.claims)
        self.claims = Claims(dep, run, dropped)
        self.stats = self.claims.stats  # service -> counters, all its processes
        self.stats_t = self.claims.stats_t  # service -> latest t of its believed stats
        self.events: list[dict[str, Any]] = []  # faults, warnings and errors
        self.last_log: dict[str, str] = {}  # log topic -> the last line logged on it
        self.refusals = Refusals()  # messages believed of nobody: never ingested
        self.counts: dict[str, int] = {}  # decoded messages by schema
        self.first_ns: int | None = None
        self.last_ns: int | None = None

    def sc(self, name: str) -> CraftData:
        """The data of spacecraft ``name``, made on first use."""
        craft = self.craft.get(name)
        if craft is None:
            craft = self.craft[name] = CraftData()
        return craft

    def seen(self, recv_ns: int) -> None:
        """Any message received (decodable or not) at wall time ``recv_ns``."""
        if self.first_ns is None:
            self.first_ns = recv_ns
        self.last_ns = recv_ns

    def received(self, msg: Message) -> None:
        """Any message decoded, before the ground decides whether to believe it: what arrived
        from its publisher, which its stats are checked against (``Claims``)."""
        self.claims.seen(msg)

    def ingest(self, topic: str, msg: Message) -> None:
        """Update the time series with one decoded message (one ``refusals`` accepts)."""
        b = msg.body
        if msg.schema == "stats" and not self.claims.claim(msg, self.sim_t):
            return  # an impossible claim: recorded, counted, never believed
        self.counts[msg.schema] = self.counts.get(msg.schema, 0) + 1
        if msg.schema == "clock":
            self.clock_seen = True
            self.sim_t = max(self.sim_t, msg.t)
            if b["final"]:
                self.final_seen = True
                self.final_t = msg.t
        elif not self.clock_seen:
            self.sim_t = max(self.sim_t, msg.t)
        if msg.schema == "truth":
            self.sc(b["sc"]).truth.add(msg.t, [*b["r_N"], *b["v_N"]])
        elif msg.schema == "nav":
            self.sc(b["sc"]).nav.add(msg.t, [*b["x_hill"], 1.0 if b["valid"] else 0.0])
        elif msg.schema == "cmd" and b["for_t"] > self.sim_t + self.dep.run.fsw_period + 1e-6:
            # for a step the clock has not come near: no controller sent it, and the environment
            # refuses it (counted there, services.flight.command_gate); it must not become the
            # command in force of the time series
            pass
        elif msg.schema == "cmd":
            self.sc(b["sc"]).cmd.add(b["for_t"], b["sigma"])
        elif msg.schema == "gains":
            self.sc(b["sc"]).gains.append(
                GainRecord(
                    msg.t,
                    b["K"].tolist(),
                    b["L"].tolist(),
                    b["source"],
                    b["iteration"],
                    b["converged"],
                )
            )
        elif msg.schema == "status":
            self.sc(b["sc"]).status.append(StatusRecord(msg.t, dict(b)))
        elif msg.schema == "log" and b["text"]:
            self.last_log[topic] = b["text"]
        notable = msg.schema == "fault" or (
            msg.schema == "log" and b["level"] in ("warning", "error", "critical")
        )
        if notable and len(self.events) < MAX_EVENTS:
            self.events.append({"t": msg.t, "topic": topic, "src": msg.src, **b})

    def unrecorded(self) -> dict[str, int]:
        """Messages each service published that never reached the monitor
        (``Claims.unrecorded``): it can hide a loss (a process killed before its final stats
        sent more than they say), never invent one."""
        return self.claims.unrecorded()

    # -- derived quantities -----------------------------------------------------------------

    def hill(self, deputy: str) -> tuple[FloatArray, FloatArray]:
        """(t (N,), Hill state (N, 6)) of ``deputy`` vs the chief from truth, at the times
        both were received."""
        chief, dep = self.craft.get("chief"), self.craft.get(deputy)
        if chief is None or dep is None or not len(chief.truth) or not len(dep.truth):
            return np.empty(0), np.empty((0, 6))
        tc, c = chief.truth.arrays()
        td, d = dep.truth.arrays()
        common, ic, id_ = np.intersect1d(tc, td, assume_unique=False, return_indices=True)
        if not len(common):
            return np.empty(0), np.empty((0, 6))
        return common, truth_hill(self.dep, c[ic], d[id_])

    def live(self, deputy: Deputy) -> dict[str, Any]:
        """Latest values for the status line of one deputy (no J2 frame-rate term)."""
        out: dict[str, Any] = {"orbits": self.sim_t / self.period}
        craft = self.craft.get(deputy.name)
        chief = self.craft.get("chief")
        if craft is None:
            return out
        last = craft.truth.last()
        if last is not None and chief is not None:
            k = chief.truth.index.get(last[0])
            if k is not None:
                c = np.asarray(chief.truth.values[6 * k : 6 * k + 6])
                h = rv_to_hill(c[:3], c[3:], last[1][:3], last[1][3:])
                out["ey"] = float(h[1] - deputy.y_ref)
                out["x"] = float(h[0])
        cmd = craft.cmd.last()
        if cmd is not None:
            out["sigma3"] = float(cmd[1][2])
        if craft.status:
            out.update(craft.status[-1].body)
        return out


def truth_hill(dep: Deployment, chief: FloatArray, deputy: FloatArray) -> FloatArray:
    """The deputy's truth Hill state (N, 6) vs the chief's, from their inertial states (N, 6)
    at the same times: the frame every report scores in."""
    a_c = chief_acceleration(chief[:, :3], chief[:, 3:], dep.environment.j2)
    return hill_states(chief[:, :3], chief[:, 3:], a_c, deputy[:, :3], deputy[:, 3:])


def chief_acceleration(r: FloatArray, v: FloatArray, j2: bool) -> FloatArray:
    """Gravitational acceleration (N, 3) of the chief (drag off: its out-of-plane part, the
    only one the Hill frame rate uses, is negligible)."""
    eye = np.broadcast_to(np.eye(3), (len(r), 3, 3))
    return acceleration(r, v, eye, j2=j2, drag=False)


def hill_states(
    r_c: FloatArray, v_c: FloatArray, a_c: FloatArray | None, r_d: FloatArray, v_d: FloatArray
) -> FloatArray:
    """Row-wise ``rv_to_hill(r_c[k], v_c[k], r_d[k], v_d[k], a_c[k])`` for (N, 3) inputs."""
    HN = hill_frame(r_c, v_c)  # (N, 3, 3)
    h = np.cross(r_c, v_c)
    omega = h / np.einsum("ij,ij->i", r_c, r_c)[:, None]
    if a_c is not None:
        a_h = np.einsum("ij,ij->i", a_c, h) / np.einsum("ij,ij->i", h, h)
        omega = omega + a_h[:, None] * r_c
    dr = r_d - r_c
    dv = v_d - v_c - np.cross(omega, dr)
    return np.concatenate(
        (np.einsum("nij,nj->ni", HN, dr), np.einsum("nij,nj->ni", HN, dv)), axis=1
    )


@dataclass
class DeputySeries:
    """One deputy's truth Hill states at the sample times, t (N,) and hill (N, 6), with its
    LQR gains K (1, 4) and L (1, 5) of the nominal model, and the optimal gains K* (1, 4) and
    L* (1, 5) of the truth's linear model (``services.model.true_lqr_gains``; None when the
    truth has none), the reference every gain error is scored against."""

    deputy: Deputy
    t: FloatArray
    hill: FloatArray
    K_lqr: FloatArray
    L_lqr: FloatArray
    K_true: FloatArray | None = None
    L_true: FloatArray | None = None

    @property
    def label(self) -> str:
        """The deputy as a legend names it: its name, and its controller when the name does not
        say it (``lqr``, ``ddvi``, ``fit (ddvi model-fit)``)."""
        d = self.deputy
        return d.name if d.name == d.controller else f"{d.name} ({d.label})"
