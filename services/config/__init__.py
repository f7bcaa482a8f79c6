"""Deployments: the typed deployment (``deployment``), its semantic checks (``validation``;
what its patterns name: ``wiring``; the physical range of every number: ``ranges``; the truth's
atmosphere: ``atmosphere``) and its
files (``files``); the strict TOML reader they use is ``ddvi_core.tables``.  A deployment is
data: reading one starts nothing.

May import: ``ddvi_core``, ``services.interface`` (its topics and the links' declaration).
Not the bus (so not zenoh), models, processes or tools.
"""

from services.config.atmosphere import parse_epoch
from services.config.deployment import (
    Chief,
    Deployment,
    DeploymentError,
    Deputy,
    Fault,
    Orbit,
    controller_label,
)
from services.config.files import (
    load_deployment,
    read_table,
    resolve,
    with_ros2,
    write_deployment,
)
from services.config.validation import (
    check_fault,
    check_panel,
    check_ros2_endpoint,
    deployment_from_table,
)
from services.config.wiring import check_kill, check_link_fault, link_from_params

__all__ = [
    "Chief",
    "Deployment",
    "DeploymentError",
    "Deputy",
    "Fault",
    "Orbit",
    "check_fault",
    "check_kill",
    "check_link_fault",
    "check_panel",
    "check_ros2_endpoint",
    "controller_label",
    "deployment_from_table",
    "link_from_params",
    "load_deployment",
    "parse_epoch",
    "read_table",
    "resolve",
    "with_ros2",
    "write_deployment",
]
