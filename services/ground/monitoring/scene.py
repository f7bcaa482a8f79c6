"""The formation as a 3D scene for Foxglove's 3D panel, in Foxglove's own schemas (``foxglove-sdk``:
``foxglove.FrameTransforms``, ``foxglove.SceneUpdate``, protobuf), made from the truth and the
navigation the run's bus carries; the monitor records it and the live view serves it.

The scene's fixed frame is the chief's Hill frame ``hill`` (x radial, y along-track, z orbit
normal, m), the chief at its origin.  At every flight-software step (the truth of every craft
at that time has come):

    scene/transforms   foxglove.FrameTransforms: ``hill`` -> ``<sc>``, each deputy's body frame
                       (its true position in the Hill frame, its attitude relative to it)
    scene/formation    foxglove.SceneUpdate: the chief; each deputy's body (its bus and drag
                       panel, in its body frame, drawn ``BODY_SCALE`` times its size), its
                       slot (0, y_ref, 0) and its trail over the last orbit

and with each deputy's navigation sample on a flight-software step:

    scene/<sc>/estimate  foxglove.SceneUpdate: the navigated position and its 3-sigma
                         covariance ellipsoid (the filter's position covariance; none
                         when it is zero, without navigation noise)

Every message is whole (nothing depends on an earlier one), so the last one of each channel is
the scene: what a client joining late is sent (``services.ground.monitoring.live_latch``).
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from services.config import Deployment
from services.ground.storage.recording import ns
from services.interface import Message
from services.model import facet_normal, on_grid, orbit_period

log = logging.getLogger("ddvi.scene")

SCENE_FRAME = "hill"
"""The scene's fixed frame: the chief's Hill frame, the chief at its origin."""
TRANSFORMS_TOPIC = "scene/transforms"
FORMATION_TOPIC = "scene/formation"
BODY_SCALE = 200.0
"""How many times its size a spacecraft is drawn: the formation spans tens of km, where a
body of true size (0.3 m) would not be a pixel."""
BUS_SIZE = (0.3, 0.1, 0.1)  # m, body x, y, z: a 3U bus
PENDING_STEPS = 8  # steps whose truth is awaited at once: more means one never completes
SIGMAS = 3.0  # the covariance ellipsoid's extent in standard deviations
PALETTE = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2")
"""Each deputy's colour, in the deployment's order (the layout's plots use the same)."""


def estimate_topic(deputy: str) -> str:
    """``scene/<deputy>/estimate``: a deputy's navigated position and covariance ellipsoid."""
    return f"scene/{deputy}/estimate"


@dataclass(frozen=True)
class SceneMessage:
    """One scene message, encoded: its channel, its schema (Foxglove's, from the SDK), the
    protobuf bytes and its simulation time (ns)."""

    topic: str
    schema: Any  # foxglove.Schema: name, encoding "protobuf", the FileDescriptorSet
    data: bytes
    log_ns: int


# The scene's geometry is a few 3-vectors a step: in plain floats, each helper is a few
# microseconds, where numpy's per-call overhead (ddvi_core.orbit's stacked helpers) would make
# the scene the monitor's largest cost.
Vec = tuple[float, float, float]
Mat = tuple[Vec, Vec, Vec]


def hill_axes(r: Any, v: Any) -> Mat:
    """[HN]: the rows are the Hill frame's axes in N (``ddvi_core.orbit.hill_frame``)."""
    rx, ry, rz = float(r[0]), float(r[1]), float(r[2])
    vx, vy, vz = float(v[0]), float(v[1]), float(v[2])
    hx, hy, hz = ry * vz - rz * vy, rz * vx - rx * vz, rx * vy - ry * vx
    rn, hn = math.sqrt(rx * rx + ry * ry + rz * rz), math.sqrt(hx * hx + hy * hy + hz * hz)
    x = (rx / rn, ry / rn, rz / rn)
    z = (hx / hn, hy / hn, hz / hn)
    y = (z[1] * x[2] - z[2] * x[1], z[2] * x[0] - z[0] * x[2], z[0] * x[1] - z[1] * x[0])
    return x, y, z


def mrp_dcm(sigma: Any) -> Mat:
    """[BN] of the MRP sigma_BN (``ddvi_core.orbit.mrp_to_dcm``)."""
    s1, s2, s3 = float(sigma[0]), float(sigma[1]), float(sigma[2])
    q = s1 * s1 + s2 * s2 + s3 * s3
    d = (1.0 + q) ** 2
    a, b = 8.0 / d, 4.0 * (1.0 - q) / d
    return (
        (1.0 + a * (s1 * s1 - q), a * s1 * s2 + b * s3, a * s1 * s3 - b * s2),
        (a * s2 * s1 - b * s3, 1.0 + a * (s2 * s2 - q), a * s2 * s3 + b * s1),
        (a * s3 * s1 + b * s2, a * s3 * s2 - b * s1, 1.0 + a * (s3 * s3 - q)),
    )


def times_transpose(A: Mat, B: Mat) -> Mat:
    """A B^T: [BH] = [BN] [HN]^T."""
    return tuple(  # type: ignore[return-value]
        tuple(a[0] * b[0] + a[1] * b[1] + a[2] * b[2] for b in B) for a in A
    )


def quaternion(C: Any) -> tuple[float, float, float, float]:
    """The rotation (x, y, z, w) that takes a child frame's coordinates to its parent's, for
    the DCM ``C`` = [child parent] (rows: the child's axes in the parent's): C's Euler
    parameters by Sheppard's method (``ddvi_core.orbit.dcm_to_mrp``)."""
    (c11, c12, c13), (c21, c22, c23), (c31, c32, c33) = C
    tr = c11 + c22 + c33
    squares = (1.0 + tr, 1.0 + 2.0 * c11 - tr, 1.0 + 2.0 * c22 - tr, 1.0 + 2.0 * c33 - tr)
    k = max(range(4), key=squares.__getitem__)
    m = 2.0 * math.sqrt(squares[k])  # 4 times the largest parameter
    if k == 0:
        b = (m / 4.0, (c23 - c32) / m, (c31 - c13) / m, (c12 - c21) / m)
    elif k == 1:
        b = ((c23 - c32) / m, m / 4.0, (c12 + c21) / m, (c31 + c13) / m)
    elif k == 2:
        b = ((c31 - c13) / m, (c12 + c21) / m, m / 4.0, (c23 + c32) / m)
    else:
        b = ((c12 - c21) / m, (c31 + c13) / m, (c23 + c32) / m, m / 4.0)
    sign = -1.0 if b[0] < 0.0 else 1.0  # the short rotation
    return sign * b[1], sign * b[2], sign * b[3], sign * b[0]


def ellipsoid(P: np.ndarray) -> tuple[tuple[float, float, float, float], list[float]]:
    """The orientation (a quaternion, ``quaternion``) and the diameters (m) of the
    ``SIGMAS``-sigma ellipsoid of a position covariance ``P`` (3, 3)."""
    values, axes = np.linalg.eigh(0.5 * (P + P.T))
    rows = axes.T.tolist()  # each principal axis in the Hill frame
    (a, b, c), (d, e, f), (g, h, i) = rows
    if a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g) < 0:
        rows[2] = [-v for v in rows[2]]  # a rotation, not a reflection
    diameters = [2.0 * SIGMAS * math.sqrt(max(v, 0.0)) for v in values.tolist()]
    return quaternion(rows), diameters


def _rgba(hex_colour: str, alpha: float = 1.0) -> Any:
    from foxglove.messages import Color

    r, g, b = (int(hex_colour[k : k + 2], 16) / 255.0 for k in (1, 3, 5))
    return Color(r=r, g=g, b=b, a=alpha)


class Scene:
    """Builds the scene of one run of ``dep`` from its bus messages (``message``)."""

    def __init__(self, dep: Deployment) -> None:
        from foxglove import messages as fm

        self._fm = fm
        self.dep = dep
        self.crafts = ["chief", *(d.name for d in dep.deputy)]
        self.fsw = dep.run.fsw_period
        self.colours = {d.name: PALETTE[k % len(PALETTE)] for k, d in enumerate(dep.deputy)}
        # each deputy's colour as drawn: (body, trail, ellipsoid), made once
        self._paint = {
            sc: (_rgba(c), _rgba(c, 0.8), _rgba(c, 0.25)) for sc, c in self.colours.items()
        }
        steps = max(2, math.ceil(orbit_period(dep) / self.fsw) + 1)
        self.trails: dict[str, deque[Any]] = {d.name: deque(maxlen=steps) for d in dep.deputy}
        self._pending: dict[float, dict[str, Message]] = {}  # t -> craft -> its truth at t
        self._schemas = {
            name: getattr(fm, name).get_schema() for name in ("FrameTransforms", "SceneUpdate")
        }
        self._fixed = self._fixed_entities()

    def channels(self) -> list[tuple[str, Any]]:
        """Every scene channel: (topic, its Foxglove schema)."""
        update = self._schemas["SceneUpdate"]
        return [
            (TRANSFORMS_TOPIC, self._schemas["FrameTransforms"]),
            (FORMATION_TOPIC, update),
            *((estimate_topic(sc), update) for sc in self.trails),
        ]

    def message(self, topic: str, msg: Message) -> list[SceneMessage]:
        """The scene messages a bus message completes (none for most)."""
        if not on_grid(msg.t, self.fsw):
            return []
        if msg.schema == "truth" and msg.body["sc"] in self.crafts:
            return self._truth(msg)
        sc = msg.body.get("sc")
        if msg.schema == "nav" and sc in self.trails and topic == f"nav/{sc}/state":
            return [self._estimate(msg)]
        return []

    # -- the formation, from the truth ---------------------------------------------------------

    def _truth(self, msg: Message) -> list[SceneMessage]:
        at = self._pending.setdefault(msg.t, {})
        at[msg.body["sc"]] = msg
        if len(at) < len(self.crafts):
            if len(self._pending) > PENDING_STEPS:  # a craft's truth lost: forget the oldest
                del self._pending[min(self._pending)]
            return []
        for t in [t for t in self._pending if t <= msg.t]:  # this step, and any left incomplete
            del self._pending[t]
        return self._formation(msg.t, at)

    def _formation(self, t: float, truth: dict[str, Message]) -> list[SceneMessage]:
        fm = self._fm
        chief = truth["chief"].body
        HN = hill_axes(chief["r_N"], chief["v_N"])
        stamp = self._stamp(t)
        transforms, trails = [], []
        for sc, trail in self.trails.items():
            body = truth[sc].body
            d = (body["r_N"] - chief["r_N"]).tolist()
            rho = [h[0] * d[0] + h[1] * d[1] + h[2] * d[2] for h in HN]
            x, y, z, w = quaternion(times_transpose(mrp_dcm(body["sigma_BN"]), HN))
            transforms.append(
                fm.FrameTransform(
                    timestamp=stamp,
                    parent_frame_id=SCENE_FRAME,
                    child_frame_id=sc,
                    translation=fm.Vector3(x=rho[0], y=rho[1], z=rho[2]),
                    rotation=fm.Quaternion(x=x, y=y, z=z, w=w),
                )
            )
            trail.append(fm.Point3(x=rho[0], y=rho[1], z=rho[2]))  # one new point a step
            line = fm.LinePrimitive(
                type=fm.LinePrimitiveLineType.LineStrip,
                thickness=2.0,
                scale_invariant=True,
                points=list(trail),
                color=self._paint[sc][1],
            )
            trails.append({"frame_id": SCENE_FRAME, "id": f"trail/{sc}", "lines": [line]})
        entities = [fm.SceneEntity(timestamp=stamp, **e) for e in (*self._fixed, *trails)]
        frames = fm.FrameTransforms(transforms=transforms)
        return [
            self._encoded(TRANSFORMS_TOPIC, "FrameTransforms", frames, t),
            self._encoded(FORMATION_TOPIC, "SceneUpdate", fm.SceneUpdate(entities=entities), t),
        ]

    def _fixed_entities(self) -> list[dict[str, Any]]:
        """The chief, each deputy's body (frame-locked to its body frame) and its slot: the
        same at every step (the scene is whole in each message)."""
        fm = self._fm
        size = BODY_SCALE * BUS_SIZE[0]
        ball = fm.SpherePrimitive(size=fm.Vector3(x=size, y=size, z=size), color=_rgba("#b0b0b0"))
        label_up = fm.Pose(position=fm.Vector3(z=1.5 * size))
        out: list[dict[str, Any]] = [
            {
                "frame_id": SCENE_FRAME,
                "id": "chief",
                "spheres": [ball],
                "texts": [self._label("chief", label_up)],
            }
        ]
        for d in self.dep.deputy:
            colour = self.colours[d.name]
            out.append(
                {
                    "frame_id": d.name,
                    "id": f"body/{d.name}",
                    "frame_locked": True,
                    "cubes": self._body(colour, d.name),
                    "texts": [self._label(d.name, label_up)],
                }
            )
            slot = fm.Pose(position=fm.Vector3(y=d.y_ref))
            ring = fm.SpherePrimitive(
                pose=slot, size=fm.Vector3(x=size, y=size, z=size), color=_rgba(colour, 0.35)
            )
            out.append({"frame_id": SCENE_FRAME, "id": f"slot/{d.name}", "spheres": [ring]})
        return out

    def _body(self, colour: str, sc: str) -> list[Any]:
        """The bus and its drag panel (normal at the spacecraft's normal angle in the body x-y
        plane; the panel fault's changes are not drawn), ``BODY_SCALE`` times their size."""
        fm = self._fm
        spec = self.dep.spacecraft
        bus = fm.CubePrimitive(
            size=fm.Vector3(**dict(zip("xyz", (BODY_SCALE * s for s in BUS_SIZE), strict=True))),
            color=_rgba("#d0d0d0"),
        )
        side = BODY_SCALE * math.sqrt(spec.area)
        nx, ny, _ = facet_normal(spec.normal_angle)
        yaw = math.atan2(ny, nx)  # the panel's x axis along its normal: a rotation about z
        panel = fm.CubePrimitive(
            pose=fm.Pose(orientation=fm.Quaternion(z=math.sin(yaw / 2), w=math.cos(yaw / 2))),
            size=fm.Vector3(x=0.02 * side, y=side, z=side),
            color=_rgba(colour),
        )
        return [bus, panel]

    def _label(self, text: str, pose: Any) -> Any:
        return self._fm.TextPrimitive(
            pose=pose,
            billboard=True,
            font_size=14.0,
            scale_invariant=True,
            color=_rgba("#ffffff"),
            text=text,
        )

    # -- a deputy's navigated estimate ---------------------------------------------------------

    def _estimate(self, msg: Message) -> SceneMessage:
        fm = self._fm
        sc, b = msg.body["sc"], msg.body
        x = b["x_hill"]
        centre = fm.Vector3(x=x[0], y=x[1], z=x[2])
        body, _, shade = self._paint[sc]
        dot = 0.5 * BODY_SCALE * BUS_SIZE[0]
        spheres = [
            fm.SpherePrimitive(
                pose=fm.Pose(position=centre, orientation=fm.Quaternion(w=1.0)),
                size=fm.Vector3(x=dot, y=dot, z=dot),
                color=body,
            )
        ]
        P = b["cov"][:3, :3]
        if P.any():  # no navigation noise, no ellipsoid (nor its eigen-decomposition to pay)
            (qx, qy, qz, qw), (dx, dy, dz) = ellipsoid(P)
            orientation = fm.Quaternion(x=qx, y=qy, z=qz, w=qw)
            spheres.append(
                fm.SpherePrimitive(
                    pose=fm.Pose(position=centre, orientation=orientation),
                    size=fm.Vector3(x=dx, y=dy, z=dz),
                    color=shade,
                )
            )
        entity = fm.SceneEntity(
            timestamp=self._stamp(msg.t),
            frame_id=SCENE_FRAME,
            id=f"estimate/{sc}",
            spheres=spheres,
        )
        update = fm.SceneUpdate(entities=[entity])
        return self._encoded(estimate_topic(sc), "SceneUpdate", update, msg.t)

    # -- encoding ------------------------------------------------------------------------------

    def _stamp(self, t: float) -> Any:
        whole = ns(t)
        return self._fm.Timestamp(whole // 1_000_000_000, whole % 1_000_000_000)

    def _encoded(self, topic: str, kind: str, message: Any, t: float) -> SceneMessage:
        return SceneMessage(topic, self._schemas[kind], message.encode(), ns(t))


def open_scene(dep: Deployment | None) -> Scene | None:
    """The scene of ``dep``'s runs, or None (said once) without a deployment or without
    foxglove-sdk, whose schemas it is written in."""
    if dep is None:
        return None
    try:
        return Scene(dep)
    except ImportError:
        log.info("no 3D scene: foxglove-sdk, whose schemas it is written in, is not installed")
        return None
