"""One mission message of every exposed ROS 2 type, a message as plain data (to compare messages
of two type stores), the ``.msg`` folder a ROS-less tool reads, and a Zenoh router of a test's
own."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from services.ros2 import conversions as cv
from services.ros2 import messages

T = 5432.123456789
"""A simulation time (s) with a fraction that no binary float holds exactly."""

HILL_STATE = np.array([-12.5, 230.75, 3.25, 0.0125, -0.031, 0.0042])
SIGMA = np.array([0.05, -0.12, 0.2])


def sample(ros_type: str) -> Any:
    """A message of ``ros_type`` as the mission would send it, every field non-default."""
    covariance = np.diag([4.0, 9.0, 1.0, 1e-4, 2e-4, 5e-5])
    covariance[0, 3] = covariance[3, 0] = 1e-3
    build = {
        messages.CLOCK: lambda: cv.clock_message(T),
        messages.ODOMETRY: lambda: cv.odometry_message(
            T, "lqr", HILL_STATE, sigma=SIGMA, covariance=covariance
        ),
        messages.ATTITUDE_COMMAND: lambda: cv.attitude_command(T, "ddvi", SIGMA),
        messages.GAINS: lambda: cv.gains_message([[1.5e-3, -2.0e-2, 3.0, -4.5e1]]),
        messages.TF: lambda: cv.tf_message(
            [
                cv.hill_transform(T, "lqr", HILL_STATE, SIGMA),
                cv.hill_transform(T, "ddvi", -HILL_STATE),
            ]
        ),
        messages.ALTITUDE: lambda: cv.altitude_message(T, "lqr", 301234.5625),
        messages.DIAGNOSTICS: lambda: cv.diagnostic_array(
            T,
            [
                cv.Status("ddvi/nav-lqr", cv.Level.OK, "tracking", "lqr", {"rate_hz": "10"}),
                cv.Status("ddvi/ctrl-ddvi", cv.Level.ERROR, "stale input", "ddvi"),
            ],
        ),
    }
    return build[ros_type]()


def plain(value: Any) -> Any:
    """A message as nested dicts, lists and numbers (any type store's classes alike)."""
    if dataclasses.is_dataclass(value):
        return {f.name: plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    return value


def write_definitions(folder: Path, ros_types: tuple[str, ...]) -> None:
    """Write ``<folder>/<package>/msg/<Name>.msg`` of every type ``ros_types`` use."""
    for ros_type in ros_types:
        for name, text in messages.message_definitions(ros_type).items():
            path = folder / (name + ".msg")
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text)


def zenoh_router(port: int) -> zenoh.Session:
    """A Zenoh router listening on 127.0.0.1:``port`` only, scouting off: what a ROS 2 user's
    ``rmw_zenohd`` is to the ROS 2 side."""
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps("router"))
    config.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    config.insert_json5("connect/endpoints", "[]")
    config.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(config)
