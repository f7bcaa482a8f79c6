"""Deployments: the strict TOML reader, the typed deployment, its semantic checks and file
resolution.  A deployment is data: reading one starts nothing.

May import: ``ddvi_core``, ``services.bus`` (its link model). Not models, processes or tools.
"""

from services.config.deployment import (
    Deployment,
    DeploymentError,
    Deputy,
    Orbit,
    check_panel,
    deployment_from_table,
    load_deployment,
    read_table,
    resolve,
    write_deployment,
)

__all__ = [
    "Deployment",
    "DeploymentError",
    "Deputy",
    "Orbit",
    "check_panel",
    "deployment_from_table",
    "load_deployment",
    "read_table",
    "resolve",
    "write_deployment",
]
