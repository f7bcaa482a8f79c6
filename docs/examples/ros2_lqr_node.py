"""A ROS 2 node that flies a deputy on the LQR gains, written with zenoh-ros2-sdk (it needs no
ROS 2 installation): the controller of a deputy with ``controller = "ros2"`` (docs/ros2.md,
"A ROS 2 controller in the loop").

    python docs/examples/ros2_lqr_node.py DEPLOYMENT --deputy rosd &
    ddvi run DEPLOYMENT --ros2

It reads ``/clock``, the deputy's ``/<sc>/odom`` and ``/<sc>/altitude`` and, at each
flight-software step T (the clock at T and the navigation sample measured at T), publishes on
``/<sc>/cmd_attitude`` the attitude the built-in LQR controller would command:

    u      = -K x + L v                         K, L: the LQR gains of the nominal model
    x      = [x, y, xdot, ydot]                 the Odometry's in-plane state (chief_hill axes)
    v      = [1, cos a, sin a, cos 2a, sin 2a]  a = a0 + n T, the chief's argument of latitude
    sigma3 = drag_allocation(u / rho(h) * rho(h0), facet normal angle, attitude limit)

(the allocation makes the facet's drag linear in u at every altitude h, docs/methods.md), as a
``geometry_msgs/msg/QuaternionStamped`` in frame ``<sc>/hill`` stamped T.  K, L, a0, n, h0 and
the allocation's constants are the deployment's, computed here with this project's model, as the
built-in controller computes them; an rclpy node on ROS 2 Jazzy (``RMW_IMPLEMENTATION=
rmw_zenoh_cpp``, ``use_sim_time:=true``) runs the same loop with those numbers as parameters.

In lock-step the mission waits for each command (past ``run.hang_timeout`` it ends, naming this
node); in real time it flies on what arrives.  The node ends once it has commanded the mission's
last step (the last flight-software step before the mission's end), or on SIGINT/SIGTERM.
``--messages DIR`` reads the ``.msg`` definitions from DIR (zenoh-ros2-sdk otherwise downloads
ROS 2's).
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
import threading
from typing import Any

import numpy as np

from ddvi_core.constants import R_EARTH
from ddvi_core.models import drag_allocation
from services.config import load_deployment
from services.model import IN_PLANE, duration, exostate, lqr_gains, on_grid

CLOCK, ODOMETRY = "rosgraph_msgs/msg/Clock", "nav_msgs/msg/Odometry"
POINT, COMMAND = "geometry_msgs/msg/PointStamped", "geometry_msgs/msg/QuaternionStamped"


def seconds(stamp: Any) -> float:
    """A ``builtin_interfaces/Time`` in seconds (exact for the mission's steps)."""
    return stamp.sec + stamp.nanosec / 1e9


class LqrNode:
    """The deputy ``sc``'s controller: the LQR law of ``dep`` on what ROS 2 delivers."""

    def __init__(self, dep: Any, sc: str, router: tuple[str, int], domain: int) -> None:
        from zenoh_ros2_sdk import ROS2Publisher, ROS2Subscriber

        deputy = dep.deputy_named(sc)
        K, L = lqr_gains(dep, deputy)
        self.K, self.L = np.asarray(K), np.asarray(L)
        self.dep, self.sc = dep, sc
        self.fsw, self.end = dep.run.fsw_period, duration(dep)
        self.h0, self.scale = dep.chief.a - R_EARTH, dep.atmosphere.scale_height
        self.normal, self.limit = math.radians(dep.spacecraft.normal_angle), deputy.attitude_limit
        self.clock = -math.inf  # the newest /clock
        self.states: dict[float, np.ndarray] = {}  # measured time -> in-plane state
        self.altitudes: dict[float, float] = {}  # measured time -> altitude
        self.step = 0.0  # the next step to command
        self.done = threading.Event()
        self.lock = threading.Lock()
        where = {"node_name": "ddvi_lqr", "domain_id": domain, "router_ip": router[0]}
        where["router_port"] = router[1]
        self.command = ROS2Publisher(topic=f"/{sc}/cmd_attitude", msg_type=COMMAND, **where)
        store = self.command.session_mgr.store.types
        self.header, self.stamp = store["std_msgs/msg/Header"], store["builtin_interfaces/msg/Time"]
        self.quaternion = store["geometry_msgs/msg/Quaternion"]
        self.subscriptions = [
            ROS2Subscriber(topic="/clock", msg_type=CLOCK, callback=self.on_clock, **where),
            ROS2Subscriber(topic=f"/{sc}/odom", msg_type=ODOMETRY, callback=self.on_odom, **where),
            ROS2Subscriber(
                topic=f"/{sc}/altitude", msg_type=POINT, callback=self.on_altitude, **where
            ),
        ]

    def on_clock(self, msg: Any) -> None:
        with self.lock:
            self.clock = max(self.clock, seconds(msg.clock))
            self.fly()

    def on_odom(self, msg: Any) -> None:
        t = seconds(msg.header.stamp)
        if not on_grid(t, self.fsw):
            return  # a sample between steps: no step flies on it
        pose, twist = msg.pose.pose.position, msg.twist.twist.linear  # identity orientation
        state = np.array([pose.x, pose.y, pose.z, twist.x, twist.y, twist.z])
        with self.lock:
            self.states[t] = state[list(IN_PLANE)]
            self.fly()

    def on_altitude(self, msg: Any) -> None:
        t = seconds(msg.header.stamp)
        if not on_grid(t, self.fsw):
            return
        with self.lock:
            self.altitudes[t] = -msg.point.x
            self.fly()

    def fly(self) -> None:
        """Command every step whose clock and navigation sample are in (the lock held); a
        node that came late (in real time) flies from the first step it has a sample for."""
        later = [t for t in self.states if t > self.step]
        if self.step not in self.states and later:
            self.step = min(later)
        while (
            not self.done.is_set()
            and self.clock >= self.step - 1e-6
            and self.step in self.states
            and self.step in self.altitudes
        ):
            T = self.step
            x, h = self.states.pop(T), self.altitudes.pop(T)
            v, _ = exostate(self.dep, T)
            u = float((-self.K @ x + self.L @ v)[0])
            ratio = math.exp(-(h - self.h0) / self.scale)  # the drag at h over that at h0
            sigma3, _ = drag_allocation(u / ratio, self.normal, self.limit)
            self.publish(T, sigma3)
            self.step = T + self.fsw
            if self.step >= self.end - 1e-6:  # the mission's last step is before its end
                self.done.set()

    def publish(self, T: float, sigma3: float) -> None:
        """sigma = [0, 0, sigma3] as the quaternion [2 sigma, 1 - |sigma|^2] / (1 + |sigma|^2)."""
        s2 = sigma3 * sigma3
        sec = math.floor(T)
        self.command.publish(
            header=self.header(
                stamp=self.stamp(sec=sec, nanosec=round((T - sec) * 1e9)),
                frame_id=f"{self.sc}/hill",
            ),
            quaternion=self.quaternion(
                x=0.0, y=0.0, z=2 * sigma3 / (1 + s2), w=(1 - s2) / (1 + s2)
            ),
        )

    def close(self) -> None:
        for subscription in self.subscriptions:
            subscription.close()
        self.command.close()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("deployment", help="the deployment the run flies")
    ap.add_argument("--deputy", required=True, help="the deputy flown from ROS 2")
    ap.add_argument("--router", default="127.0.0.1:7447", help="HOST:PORT of the Zenoh router")
    ap.add_argument("--domain", type=int, default=None, help="ROS domain (default ros2.domain_id)")
    ap.add_argument("--messages", help="a folder of .msg definitions (no download)")
    args = ap.parse_args(argv)
    dep = load_deployment(args.deployment)
    if dep.deputy_named(args.deputy).controller != "ros2":
        print(f"{args.deputy} is not flown from ROS 2 (controller = 'ros2')", file=sys.stderr)
        return 2
    if args.messages:
        from zenoh_ros2_sdk import get_registry

        get_registry(args.messages)  # the registry every publisher and subscriber reads
    host, _, port = args.router.rpartition(":")
    domain = dep.ros2.domain_id if args.domain is None else args.domain
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    node = LqrNode(dep, args.deputy, (host, int(port)), domain)
    try:
        while not (stop.is_set() or node.done.is_set()):
            node.done.wait(0.2)
    finally:
        node.close()
        from zenoh_ros2_sdk import ZenohSession

        if ZenohSession._instance is not None:
            ZenohSession._instance.close()
    print(f"flew {args.deputy} up to t = {node.step - node.fsw:g} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
