"""The message catalogue: every message type of the system, each field with its kind, unit
and meaning, and the header every message carries (docs/design.md, "The bus").

``SCHEMAS`` is data: one ``Schema`` per message type, each a mapping of field name to a field
kind (``services.interface.fields``) that also states the field's unit and a one-line
description.  ``HEADER`` describes the header keys.  The codec (``services.interface.codec``)
validates against this table; ``python -m services.interface.reference`` renders it into
``docs/interface.md``.  This module has no state.

Units: SI (m, m/s, s, rad); "1" is a pure number, "count" a number of things, "-" (an empty
``unit``) a name, flag or text.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import msgspec

from services.interface.fields import Array, Bool, Field, Float, Int, IntMap, ScalarMap, Str


class Message(msgspec.Struct, frozen=True):
    """One decoded, validated message. Array fields of ``body`` are float64 numpy arrays.
    (An immutable msgspec struct: a bus builds one per message, at a tenth of a dataclass's
    cost.)"""

    schema: str
    version: int
    seq: int
    t: float
    src: str
    body: dict[str, Any]
    boot: int = 0


@dataclass(frozen=True)
class HeaderField:
    """One key of the message header: its wire type, unit and meaning."""

    name: str
    type: str
    unit: str
    doc: str


HEADER: tuple[HeaderField, ...] = (
    HeaderField("schema", "str", "", "the message type, a key of SCHEMAS"),
    HeaderField("version", "int", "", "the message type's version; a receiver takes only its own"),
    HeaderField("seq", "int >= 0", "count", "the publisher's sequence number on this topic"),
    HeaderField("t", "float", "s", "simulation time the message stands for (finite)"),
    HeaderField("src", "str", "", "the publishing service's name (non-empty)"),
    HeaderField(
        "boot",
        "int >= 0",
        "",
        "the publisher's boot: a random number drawn when its bus opens; a restarted publisher "
        "has a new one, and a receiver keeps a sequence window per boot",
    ),
    HeaderField("body", "map", "", "the fields of the message type, all required, no others"),
)
"""The header keys of every message, in wire order."""

HEADER_KEYS = tuple(h.name for h in HEADER)
"""The keys of a message map, exactly these."""


@dataclass(frozen=True)
class Schema:
    """One message type: its name, version and body fields (all required, no extras), and
    ``doc``, one line on what it carries."""

    name: str
    version: int
    fields: Mapping[str, Field]
    doc: str = ""


def _schemas(*items: Schema) -> dict[str, Schema]:
    return {s.name: s for s in items}


_DEPUTY = Str(doc="the deputy's name")
_SERVICE = Str(doc="the publishing service's name")

SCHEMAS: Mapping[str, Schema] = _schemas(
    Schema(
        "clock",
        1,
        {
            "step": Int(
                unit="count", doc="index of this sample on the navigation grid (0 at t = 0)"
            ),
            "dt": Float(unit="s", doc="the navigation sample period, run.nav_period"),
            "fsw": Bool(doc="t is a flight-software step (a multiple of run.fsw_period)"),
            "mode": Str(("lockstep", "realtime"), doc="how the environment paces time (run.mode)"),
            "final": Bool(doc="the mission's last clock: every service finishes"),
        },
        "the environment's simulation clock",
    ),
    Schema(
        "truth",
        1,
        {
            "sc": Str(doc="the craft: chief or a deputy's name"),
            "r_N": Array((3,), unit="m", doc="the craft's position in the inertial frame N"),
            "v_N": Array((3,), unit="m/s", doc="the craft's velocity in the inertial frame N"),
            "sigma_BN": Array(
                (3,), unit="1", doc="the craft's attitude: body B relative to N, MRP"
            ),
        },
        "the true inertial state and attitude of one craft",
    ),
    Schema(
        "exo",
        1,
        {
            "v": Array((None,), unit="1", doc="exosystem state [1, cos u, sin u, cos 2u, sin 2u]"),
            "phase": Float(unit="rad", doc="the chief's argument of latitude u(t)"),
        },
        "the exosystem state v(t) the controllers regulate against (v' = E v)",
    ),
    Schema(
        "nav",
        2,
        {
            "sc": _DEPUTY,
            "x_hill": Array(
                (6,),
                unit="m, m/s",
                doc="[x, y, z, xdot, ydot, zdot] relative to the chief: the filter's estimate "
                "(navigation.filter), or the measurement with its noise; with the bias",
            ),
            "z_hill": Array(
                (6,),
                unit="m, m/s",
                doc="the measurement x_hill was estimated from: the relative state with its "
                "noise and bias, before the filter (x_hill itself without one)",
            ),
            "cov": Array(
                (6, 6),
                unit="m^2, m^2/s, m^2/s^2",
                doc="x_hill's error covariance, position block m^2, cross m^2/s, velocity "
                "m^2/s^2 (the white noise's only: a bias is not in it; zero without noise)",
            ),
            "altitude": Float(unit="m", doc="the deputy's own altitude above R_E"),
            "valid": Bool(doc="the sample is a navigation solution (always true)"),
        },
        "navigation's relative state of one deputy",
    ),
    Schema(
        "cmd",
        1,
        {
            "sc": _DEPUTY,
            "sigma": Array(
                (3,), unit="1", doc="attitude relative to the Hill frame, MRP; u = sigma3"
            ),
            "for_t": Float(unit="s", doc="the flight-software step the command is for"),
        },
        "a controller's attitude command for one deputy",
    ),
    Schema(
        "gains",
        1,
        {
            "sc": _DEPUTY,
            "K": Array(
                (None, None),
                unit="1/m, s/m",
                doc="feedback on the in-plane state x = [x, y, xdot, ydot], u = -K x + L v",
            ),
            "L": Array((None, None), unit="1", doc="exosystem feedforward, u = -K x + L v"),
            "source": Str(
                ("initial", "lqr", "ddvi", "model-fit", "fallback"),
                doc="where the gains come from: K0, the nominal LQR, learned by value "
                "iteration or by the model fit, or restored",
            ),
            "iteration": Int(unit="count", doc="value-iteration steps that produced them"),
            "converged": Bool(
                doc="the gains are flown without exploration: LQR, learned or fallback gains "
                "(false while the controller explores, on K0 or on its fallback)"
            ),
        },
        "the gains (K, L) a deputy's controller flies",
    ),
    Schema(
        "status",
        1,
        {
            "sc": _DEPUTY,
            "mode": Str(doc="the controller's mode: lqr or ddvi"),
            "phase": Str(
                doc="lqr, exploring, learned, relearning, fallback or exploring-on-fallback"
            ),
            "samples": Int(unit="count", doc="navigation samples the learner has collected"),
            "intervals": Int(unit="count", doc="learning intervals the learner has collected"),
            "rank": Int(unit="count", doc="rank of the learner's data matrix at its last try"),
            "rank_needed": Int(unit="count", doc="the rank learning needs"),
            "counters": IntMap(unit="count", doc="the controller's counters"),
        },
        "a controller's mode, phase and learning progress",
    ),
    Schema(
        "fault",
        1,
        {
            "kind": Str(doc="kill, panel, bias, outage or link (its topic's)"),
            "target": Str(
                doc="a service (kill), a deputy (panel, bias, outage), a subscriber pattern (link)"
            ),
            "params": ScalarMap(
                unit="per key",
                doc="panel: area_factor (1), normal_angle (deg); bias: px py pz (m), vx vy vz "
                "(m/s); outage: duration_orbits (chief orbits); link: from, topic, delay and "
                "jitter (s), loss, duplicate, reorder (1)",
            ),
        },
        "a fault the ground injects",
    ),
    Schema(
        "stats",
        1,
        {
            "service": _SERVICE,
            "counters": IntMap(unit="count", doc="the bus's counters and the service's own"),
        },
        "a service's counters (received, rejected, late, ...)",
    ),
    Schema(
        "recorded",
        1,
        {
            "messages": Int(unit="count", doc="messages the monitor has recorded so far"),
        },
        "the monitor's acknowledgement: it has recorded the clock at t and what came before it",
    ),
    Schema(
        "log",
        1,
        {
            "service": _SERVICE,
            "level": Str(doc="info, warning or error"),
            "text": Str(doc="the log line (at most 2000 characters)"),
        },
        "a service's log line, for the ground",
    ),
)
"""Every message type of the system, by name."""


UPGRADES: Mapping[tuple[str, int], Callable[[dict[str, Any]], dict[str, Any]]] = {
    # nav 1 had no measurement, and its first recordings no covariance: the estimate stands
    # in for the measurement (it is the measurement without a filter), an unknown
    # covariance is recorded as zero
    ("nav", 1): lambda body: {"z_hill": body.get("x_hill"), "cov": [[0.0] * 6] * 6, **body},
}
"""How a recorded body of an older version becomes the current one, by (schema, version)."""


def upgrade(schema: str, version: int, body: Any) -> tuple[Any, int]:
    """A recorded message's body and version, brought to the current version of its schema
    through UPGRADES one version at a time, as far as they go: the version returned is the
    current one only when the upgrade succeeded (a body that is not a map, a newer version or
    an older one with no upgrade come back as they are, for the caller to refuse).  Live
    messages are not upgraded: a sender of another version is refused."""
    spec = SCHEMAS.get(schema)
    while (
        spec is not None
        and isinstance(body, dict)
        and isinstance(version, int)
        and version < spec.version
        and (schema, version) in UPGRADES
    ):
        body, version = UPGRADES[(schema, version)](body), version + 1
    return body, version
