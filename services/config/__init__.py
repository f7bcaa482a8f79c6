"""Deployments: the typed deployment (``deployment``), its semantic checks (``validation``; the
physical range of every number: ``ranges``) and its files (``files``); the strict TOML reader
they use is ``ddvi_core.tables``.  A deployment is data: reading one starts nothing.

May import: ``ddvi_core``, ``services.bus`` (its link model). Not models, processes or tools.
"""

from services.config.deployment import (
    Deployment,
    DeploymentError,
    Deputy,
    Orbit,
    controller_label,
)
from services.config.files import load_deployment, read_table, resolve, write_deployment
from services.config.validation import check_panel, deployment_from_table

__all__ = [
    "Deployment",
    "DeploymentError",
    "Deputy",
    "Orbit",
    "check_panel",
    "controller_label",
    "deployment_from_table",
    "load_deployment",
    "read_table",
    "resolve",
    "write_deployment",
]
