"""The ground monitor's memory of a run, and the run report written from it.

``RunData`` keeps, per spacecraft, the time series the report needs (truth, navigation,
commands, gains, controller status) in compact ``array('d')`` buffers, plus the last stats
counters of every service. ``write_report`` turns it into files in the run folder:

    timeseries.csv   per truth sample time and deputy: t, orbits, the deputy's Hill state from
                     truth (vs the chief), its navigation state at that time (blank if none),
                     the commanded sigma3 in force (zero-order hold on ``for_t``), controller phase
    *.png            the paper's figures, one line per deputy (matplotlib, Agg backend)
    summary.json     run, completion, errors at the end, learned vs LQR gains, message counters
    report.md        the summary table and the figure list

The truth Hill state is ``ddvi_core.orbit.rv_to_hill`` of deputy vs chief at the same sample
time, with the chief's gravitational acceleration (two-body + J2 when the deployment has J2)
as ``a_c`` so that zdot includes the rotation of the chief's orbit plane; ``hill_states``
computes it for all samples at once (same formula, checked against rv_to_hill in the tests).
"""

from __future__ import annotations

import csv
import json
import logging
import math
from array import array
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ddvi_core.orbit import hill_frame, rv_to_hill
from ddvi_core.truth import acceleration
from services.config import Deployment, Deputy
from services.interface import Message
from services.model import duration, lqr_gains, orbit_period

log = logging.getLogger("ddvi.report")

FloatArray = NDArray[np.float64]

HILL = ("x", "y", "z", "xdot", "ydot", "zdot")
K_NAMES = ("x", "y", "xdot", "ydot")  # the in-plane state the gain K acts on (mission.IN_PLANE)
MAX_EVENTS = 200  # warnings/errors/faults kept for the report
FIGURES = {
    "hill_x.png": "Hill x (radial) position vs orbits",
    "hill_y.png": "Hill y (along-track) position vs orbits",
    "hill_xy.png": "Hill x vs y",
    "hill_xdot.png": "Hill x velocity vs orbits",
    "hill_ydot.png": "Hill y velocity vs orbits",
    "sigma3.png": "Commanded relative MRP sigma3 vs orbits",
    "gains.png": "Learned gain K vs orbits, LQR gain dashed",
    "along_track_error.png": "|y - y_ref| vs orbits (log scale)",
}


_MAX_NS = 2**64 - 1


def ns(t: float) -> int:
    """Simulation seconds as MCAP nanoseconds, clamped to the unsigned 64-bit range."""
    x = t * 1e9
    if not x > 0:
        return 0
    return _MAX_NS if x >= _MAX_NS else round(x)


class Series:
    """Samples of a fixed width keyed by time; a repeated time overwrites (duplicates)."""

    def __init__(self, width: int) -> None:
        self.width = width
        self.t = array("d")
        self.values = array("d")
        self.index: dict[float, int] = {}

    def add(self, t: float, values: Any) -> None:
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
    t: float
    K: list[list[float]]
    L: list[list[float]]
    source: str
    iteration: int
    converged: bool


@dataclass
class StatusRecord:
    t: float
    body: dict[str, Any]


@dataclass
class CraftData:
    truth: Series = field(default_factory=lambda: Series(6))  # r_N, v_N
    nav: Series = field(default_factory=lambda: Series(7))  # x_hill, valid
    cmd: Series = field(default_factory=lambda: Series(3))  # sigma, keyed by for_t
    gains: list[GainRecord] = field(default_factory=list)
    status: list[StatusRecord] = field(default_factory=list)


class RunData:
    """What the monitor learned from the bus, fed one decoded message at a time."""

    def __init__(self, dep: Deployment, run: str) -> None:
        self.dep = dep
        self.run = run
        self.period = orbit_period(dep)
        self.duration = duration(dep)
        self.craft: dict[str, CraftData] = {}
        self.sim_t = 0.0  # latest clock time (or any message's t before the first clock)
        self.clock_seen = False
        self.final_seen = False
        self.final_t: float | None = None  # time of the final clock
        self.stats: dict[str, dict[str, int]] = {}  # service -> counters, all its processes
        self._stats_last: dict[str, dict[str, int]] = {}  # service -> its process's last
        self._stats_base: dict[str, dict[str, int]] = {}  # service -> earlier processes' sum
        self.stats_t: dict[str, float] = {}  # service -> latest t of its stats
        self.events: list[dict[str, Any]] = []  # faults, warnings and errors
        self.counts: dict[str, int] = {}  # decoded messages by schema
        self.first_ns: int | None = None
        self.last_ns: int | None = None

    def sc(self, name: str) -> CraftData:
        craft = self.craft.get(name)
        if craft is None:
            craft = self.craft[name] = CraftData()
        return craft

    def seen(self, recv_ns: int) -> None:
        """Any message received (decodable or not) at wall time ``recv_ns``."""
        if self.first_ns is None:
            self.first_ns = recv_ns
        self.last_ns = recv_ns

    def ingest(self, topic: str, msg: Message) -> None:
        """Update the time series with one decoded message."""
        self.counts[msg.schema] = self.counts.get(msg.schema, 0) + 1
        b = msg.body
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
        elif msg.schema == "cmd":
            self.sc(b["sc"]).cmd.add(b["for_t"], b["sigma"])
        elif msg.schema == "gains":
            self.sc(b["sc"]).gains.append(
                GainRecord(
                    msg.t, b["K"].tolist(), b["L"].tolist(), b["source"], b["iteration"],
                    b["converged"],
                )
            )  # fmt: skip
        elif msg.schema == "status":
            self.sc(b["sc"]).status.append(StatusRecord(msg.t, dict(b)))
        elif msg.schema == "stats":
            service, counters = b["service"], dict(b["counters"])
            last = self._stats_last.get(service)
            if last is not None and counters.get("sent", 0) < last.get("sent", 0):
                # counters start again from 0: the service was restarted; keep what the
                # previous process counted
                base = self._stats_base.setdefault(service, {})
                for k, v in last.items():
                    base[k] = base.get(k, 0) + v
            self._stats_last[service] = counters
            base = self._stats_base.get(service, {})
            self.stats[service] = {k: base.get(k, 0) + counters.get(k, 0) for k in base | counters}
            self.stats_t[service] = max(msg.t, self.stats_t.get(service, -math.inf))
        notable = msg.schema == "fault" or (
            msg.schema == "log" and b["level"] in ("warning", "error", "critical")
        )
        if notable and len(self.events) < MAX_EVENTS:
            self.events.append({"t": msg.t, "topic": topic, "src": msg.src, **b})

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
        c, d = c[ic], d[id_]
        a_c = chief_acceleration(c[:, :3], c[:, 3:], self.dep.environment.j2)
        return common, hill_states(c[:, :3], c[:, 3:], a_c, d[:, :3], d[:, 3:])

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


def _hold(t_src: FloatArray, values: Any, t: FloatArray, default: Any) -> list[Any]:
    """Zero-order hold: for each t, the last value whose time is <= t (``default`` before)."""
    if len(t_src) == 0:
        return [default] * len(t)
    k = np.searchsorted(t_src, t, side="right") - 1
    return [values[i] if i >= 0 else default for i in k]


def _last_orbit(t: FloatArray, period: float) -> NDArray[np.bool_]:
    return t >= t[-1] - period


def _switches(gains: list[GainRecord], source: str, period: float) -> list[float]:
    """When (orbits) the gains switched to ``source`` from another, in order."""
    return [
        r.t / period
        for k, r in enumerate(gains)
        if r.source == source and (k == 0 or gains[k - 1].source != source)
    ]


def _norm_rel(K: FloatArray, K_ref: FloatArray) -> float | None:
    den = float(np.linalg.norm(K_ref))
    if den == 0.0 or K.shape != K_ref.shape:
        return None
    return float(np.linalg.norm(K - K_ref) / den)


# ---------------------------------------------------------------------------------------------


@dataclass
class DeputySeries:
    deputy: Deputy
    t: FloatArray
    hill: FloatArray
    K_lqr: FloatArray
    L_lqr: FloatArray

    @property
    def label(self) -> str:
        return f"{self.deputy.name} ({self.deputy.controller})"


def _deputy_summary(data: RunData, s: DeputySeries) -> dict[str, Any]:
    d = s.deputy
    craft = data.craft.get(d.name, CraftData())
    out: dict[str, Any] = {
        "controller": d.controller,
        "y_ref": d.y_ref,
        "samples": len(s.t),
        "final_along_track_error_m": None,
        "max_along_track_error_last_orbit_m": None,
        "max_radial_last_orbit_m": None,
        "final_radial_m": None,
        "gain_error_vs_lqr": None,
        "learned_at_orbits": None,
        "relearned_at_orbits": [],
        "relearning_abandoned_at_orbits": [],
        "gains": None,
        "lqr_gains": {"K": s.K_lqr.tolist(), "L": s.L_lqr.tolist()},
        "phase": craft.status[-1].body["phase"] if craft.status else None,
    }
    if len(s.t):
        ey = np.abs(s.hill[:, 1] - d.y_ref)
        ax = np.abs(s.hill[:, 0])
        last = _last_orbit(s.t, data.period)
        out.update(
            final_along_track_error_m=float(ey[-1]),
            max_along_track_error_last_orbit_m=float(ey[last].max()),
            max_radial_last_orbit_m=float(ax[last].max()),
            final_radial_m=float(ax[-1]),
        )
    if craft.gains:
        g = craft.gains[-1]
        out["gains"] = {"K": g.K, "L": g.L, "source": g.source}
        if d.controller == "ddvi":
            out["gain_error_vs_lqr"] = _norm_rel(np.asarray(g.K), s.K_lqr)
            # every switch to learned gains: the first learning, then each re-learning (or,
            # for a restarted controller, its learning from scratch)
            switches = _switches(craft.gains, "ddvi", data.period)
            if switches:
                out["learned_at_orbits"] = switches[0]
                out["relearned_at_orbits"] = switches[1:]
            # every return to the old gains after re-learning failed (Controller.learning_failed)
            out["relearning_abandoned_at_orbits"] = _switches(craft.gains, "fallback", data.period)
    return out


def _message_summary(data: RunData, monitor: dict[str, int]) -> dict[str, Any]:
    services = dict(data.stats)
    services["monitor"] = dict(monitor)  # the monitor's own counters, final

    def total(key: str) -> int:
        return sum(int(c.get(key, 0)) for c in services.values())

    return {
        "recorded": monitor.get("recorded", 0),
        "rejected": monitor.get("rejected", 0),
        "rejected_by_reason": {
            k.split(".", 1)[1]: v
            for k, v in sorted(monitor.items())
            if k.startswith("rejected.") and v
        },
        "by_schema": dict(sorted(data.counts.items())),
        "services": services,
        "totals": {
            "sent": total("sent"),
            "received": total("received"),
            "dropped": total("dropped"),
            "late": total("late_commands"),
            "missing": total("missing_commands"),
            "rejected": total("rejected"),
            "duplicated": total("duplicated"),
            "reordered": total("reordered"),
            "stale": total("stale_commands"),
            "restarted": total("restarts"),
        },
    }


def write_csv(path: Path, data: RunData, series: list[DeputySeries]) -> int:
    """Write timeseries.csv; return the number of data rows.  Empty cells: no navigation
    sample at that time, no command yet, a non-finite value."""
    header = ["t", "orbits", "deputy", "controller", *HILL]
    header += [f"nav_{k}" for k in HILL] + ["nav_valid", "sigma3", "phase"]
    # a row's numbers are formatted in two operations (t and orbits; hill, nav, valid and
    # sigma3); NaN marks an empty cell ("nan" is no other number's text)
    head_format, tail_format = ",".join(["%.10g"] * 2), ",".join(["%.10g"] * 14)
    rows: list[tuple[float, int, str]] = []
    for j, s in enumerate(series):
        craft = data.craft.get(s.deputy.name, CraftData())
        numbers = np.full((len(s.t), 16), np.nan)
        numbers[:, 0], numbers[:, 1], numbers[:, 2:8] = s.t, s.t / data.period, s.hill
        nav_t, nav = craft.nav.arrays()
        if len(nav_t):
            k = np.searchsorted(nav_t, s.t)
            found = k < len(nav_t)
            found[found] = nav_t[k[found]] == s.t[found]
            numbers[found, 8:15] = nav[k[found], :7]
        cmd_t, cmd = craft.cmd.arrays()
        numbers[:, 15] = _hold(cmd_t, cmd[:, 2].tolist(), s.t, np.nan)  # the command in force
        numbers[~np.isfinite(numbers)] = np.nan
        st_t = np.array([r.t for r in craft.status])
        phases = [_csv_cell(r.body["phase"]) for r in craft.status]
        phase = _hold(st_t, phases, s.t, "")
        labels = f"{_csv_cell(s.deputy.name)},{_csv_cell(s.deputy.controller)}"
        for i, v in enumerate(numbers.tolist()):
            tail = (tail_format % tuple(v[2:])).replace("nan", "")
            rows.append((v[0], j, f"{head_format % tuple(v[:2])},{labels},{tail},{phase[i]}"))
    rows.sort(key=lambda r: (r[0], r[1]))
    with path.open("w", newline="") as f:
        csv.writer(f).writerow(header)
        f.writelines(r[2] + "\r\n" for r in rows)  # the csv module's line ending
    return len(rows)


def _csv_cell(text: str) -> str:
    """One CSV cell as the csv module writes it (quoted only when it must be): the rows are
    written as lines, since csv.writer took 0.26 s of the 40-orbit mission's 0.39 s."""
    if any(c in text for c in ',"\r\n'):
        return '"' + text.replace('"', '""') + '"'
    return text


# fixed margins: a layout engine (tight or constrained) costs about as much as drawing
MARGINS = {"left": 0.12, "right": 0.97, "bottom": 0.11, "top": 0.92}


def warm_up() -> None:
    """Import what ``write_report`` needs (matplotlib on Agg, scipy's linear algebra for the
    LQR reference gains) and load the figures' font, ahead of time: the monitor runs this on a
    thread while the mission flies, so that the report at the end does not pay their cold
    start (1.5 to 2 s on two cores).  Never raises: the report would then pay it itself."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from ddvi_core import lqr, regulator  # noqa: F401  (scipy.linalg)

        fig = plt.figure(figsize=(1, 1))
        fig.text(0.5, 0.5, "0.1 x [m]")
        fig.canvas.draw()
        plt.close(fig)
    except Exception:
        log.exception("report warm-up failed (the report will import what it needs itself)")


def write_figures(out: Path, data: RunData, series: list[DeputySeries]) -> list[str]:
    """Write the PNG figures; return their file names."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    P = data.period
    colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    written: list[str] = []

    def save(fig: Any, name: str) -> None:
        fig.savefig(out / name, dpi=110)
        plt.close(fig)
        written.append(name)

    def line_plot(
        name: str, ylabel: str, get: Any, log: bool = False, refs: bool = False, steps: bool = False
    ) -> None:
        # room for log labels like 3.075x10^4 (a span under a decade)
        margins = {**MARGINS, "left": 0.16} if log else MARGINS
        fig, ax = plt.subplots(figsize=(8, 4.5), gridspec_kw=margins)
        for j, s in enumerate(series):
            t, y = get(s)
            if len(t):
                style = "steps-post" if steps else "default"
                ax.plot(t / P, y, color=colors[j % len(colors)], lw=1.0, label=s.label, ds=style)
                if refs:
                    ax.axhline(s.deputy.y_ref, color=colors[j % len(colors)], ls=":", lw=0.8)
        if log:
            ax.set_yscale("log")
        ax.set_xlabel("time [orbits]")
        ax.set_ylabel(ylabel)
        ax.set_title(f"{data.run}: {FIGURES[name]}")
        ax.grid(True, alpha=0.3)
        if series:
            ax.legend(loc="best", fontsize="small")
        save(fig, name)

    line_plot("hill_x.png", "x [m]", lambda s: (s.t, s.hill[:, 0]))
    line_plot("hill_y.png", "y [m]", lambda s: (s.t, s.hill[:, 1]), refs=True)
    line_plot("hill_xdot.png", "xdot [m/s]", lambda s: (s.t, s.hill[:, 3]))
    line_plot("hill_ydot.png", "ydot [m/s]", lambda s: (s.t, s.hill[:, 4]))

    def sigma3(s: DeputySeries) -> tuple[FloatArray, FloatArray]:
        t, v = data.craft.get(s.deputy.name, CraftData()).cmd.arrays()
        return t, v[:, 2]

    line_plot("sigma3.png", "commanded sigma3 [-]", sigma3, steps=True)

    def ey(s: DeputySeries) -> tuple[FloatArray, FloatArray]:
        return s.t, np.maximum(np.abs(s.hill[:, 1] - s.deputy.y_ref), 1e-6)

    line_plot("along_track_error.png", "|y - y_ref| [m]", ey, log=True)

    fig, ax = plt.subplots(figsize=(6, 6), gridspec_kw=MARGINS)
    for j, s in enumerate(series):
        if len(s.t):
            ax.plot(s.hill[:, 1], s.hill[:, 0], color=colors[j % len(colors)], lw=1.0,
                    label=s.label)  # fmt: skip
            ax.plot(s.hill[-1, 1], s.hill[-1, 0], "o", color=colors[j % len(colors)])
    ax.set_xlabel("y (along-track) [m]")
    ax.set_ylabel("x (radial) [m]")
    ax.set_title(f"{data.run}: {FIGURES['hill_xy.png']}")
    ax.grid(True, alpha=0.3)
    if series:
        ax.legend(loc="best", fontsize="small")
    save(fig, "hill_xy.png")

    fig, axes = plt.subplots(
        2, 2, figsize=(10, 6.5), sharex=True, gridspec_kw={**MARGINS, "top": 0.89, "hspace": 0.25}
    )
    learners = [(j, s) for j, s in enumerate(series) if s.deputy.controller == "ddvi"]
    for c, ax in enumerate(axes.flat):
        for j, s in learners:
            color = colors[j % len(colors)]
            gains = data.craft.get(s.deputy.name, CraftData()).gains
            if gains:
                t = np.array([g.t for g in gains]) / P
                k = np.array([np.ravel(g.K)[c] if np.size(g.K) > c else np.nan for g in gains])
                if data.sim_t > gains[-1].t:  # hold the last gain to the end of the run
                    t, k = np.append(t, data.sim_t / P), np.append(k, k[-1])
                ax.step(t, k, where="post", color=color, lw=1.2, label=f"{s.label} K")
            if s.K_lqr.size > c:
                ax.axhline(float(s.K_lqr.flat[c]), color=color, ls="--", lw=1.0,
                           label=f"{s.deputy.name} LQR")  # fmt: skip
        ax.set_title(f"K[{K_NAMES[c] if c < len(K_NAMES) else c}]")
        ax.grid(True, alpha=0.3)
        if c >= 2:
            ax.set_xlabel("time [orbits]")
    if learners:
        axes.flat[0].legend(loc="best", fontsize="small")
    else:
        axes.flat[0].text(0.5, 0.5, "no ddvi deputy", ha="center", transform=axes.flat[0].transAxes)
    fig.suptitle(f"{data.run}: {FIGURES['gains.png']}")
    save(fig, "gains.png")
    return written


def _num(v: Any, fmt: str = ".3g") -> str:
    return "-" if v is None else format(v, fmt)


def write_markdown(path: Path, summary: dict[str, Any], figures: list[str]) -> None:
    lines = [
        f"# Run {summary['run']}",
        "",
        f"- deployment: `{summary['deployment']}`",
        f"- completed: {'yes' if summary['completed'] else '**no** (partial report)'}",
        f"- simulated: {summary['sim_time_s']:.0f} s = {summary['orbits']:.2f} orbits "
        f"in {summary['wall_s']:.1f} s wall",
        "",
        "| deputy | controller | final abs(y - y_ref) [m] | max last orbit [m] | final abs(x) [m] "
        "| max abs(x) last orbit [m] | gain error vs LQR | learned at [orbits] | phase |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, d in summary["deputies"].items():
        learned = [d["learned_at_orbits"], *d.get("relearned_at_orbits", [])]
        abandoned = d.get("relearning_abandoned_at_orbits", [])
        gave_up = [f"old gains again at {t:.2f}" for t in abandoned]
        lines.append(
            f"| {name} | {d['controller']} | {_num(d['final_along_track_error_m'])} "
            f"| {_num(d['max_along_track_error_last_orbit_m'])} | {_num(d['final_radial_m'])} "
            f"| {_num(d['max_radial_last_orbit_m'])} | {_num(d['gain_error_vs_lqr'])} "
            f"| {', '.join([*(_num(t, '.2f') for t in learned), *gave_up])} "
            f"| {d['phase'] or '-'} |"
        )
    m = summary["messages"]
    tot = m["totals"]
    reasons = ", ".join(f"{k}: {v}" for k, v in m["rejected_by_reason"].items())
    reasons = f" ({reasons})" if reasons else ""
    lines += [
        "",
        f"Messages: {m['recorded']} recorded by the monitor, {m['rejected']} rejected by it"
        f"{reasons}; all services: sent {tot['sent']}, received "
        f"{tot['received']}, dropped {tot['dropped']}, rejected {tot['rejected']}, late "
        f"commands {tot['late']}, missing commands {tot['missing']}.",
        "",
        "## Figures",
        "",
    ]
    lines += [f"- [{FIGURES.get(f, f)}]({f})" for f in figures]
    lines += ["", "Data: `timeseries.csv`, `summary.json`, recording `recording.mcap`.", ""]
    if summary.get("events"):
        lines += ["## Faults, warnings and errors", ""]
        for e in summary["events"][:50]:
            text = e.get("text") or f"{e.get('kind')} on {e.get('target')} {e.get('params')}"
            lines.append(f"- t = {e['t']:.0f} s `{e['topic']}`: {text}")
        lines.append("")
    path.write_text("\n".join(lines))


def write_report(
    out: Path, data: RunData, *, completed: bool, monitor_counters: dict[str, int]
) -> dict[str, Any]:
    """Write timeseries.csv, the figures, summary.json and report.md to ``out``; return the
    summary. Figures that fail are logged and left out (the rest is still written)."""
    out.mkdir(parents=True, exist_ok=True)
    series = []
    for d in data.dep.deputy:
        t, hill = data.hill(d.name)
        K, L = lqr_gains(data.dep, d)
        series.append(DeputySeries(d, t, hill, np.asarray(K), np.asarray(L)))
    rows = write_csv(out / "timeseries.csv", data, series)
    try:
        figures = write_figures(out, data, series)
    except Exception:
        log.exception("could not draw the figures")
        figures = []
    wall = 0.0
    if data.first_ns is not None and data.last_ns is not None:
        wall = (data.last_ns - data.first_ns) / 1e9
    summary: dict[str, Any] = {
        "run": data.run,
        "deployment": data.dep.path,
        # completed: the monitor saw the final clock at the planned end (an early final clock,
        # a re-entry say, is a run that ended, not a mission that completed)
        "completed": completed and data.sim_t >= data.duration - 1e-6,
        "sim_time_s": data.sim_t,
        "orbits": data.sim_t / data.period,
        "planned_sim_time_s": data.duration,
        "wall_s": wall,
        "csv_rows": rows,
        "deputies": {s.deputy.name: _deputy_summary(data, s) for s in series},
        "messages": _message_summary(data, monitor_counters),
        "figures": figures,
        "events": data.events,
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=2, default=_json_default))
    write_markdown(out / "report.md", summary, figures)
    return summary


def _json_default(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")
