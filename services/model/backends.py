"""Choosing the truth backend a deployment names.

Kept apart from ``services.model.truth`` so that the Basilisk backend, which builds on that
module, is imported only here and only when a deployment asks for it.
"""

from __future__ import annotations

import importlib.util

from services.config import Deployment
from services.model.truth import BuiltinTruth, Truth


def backend_missing(dep: Deployment) -> str | None:
    """Why the truth backend ``environment.backend`` names cannot be opened here, in one line
    (its package is not installed), or None: found before any process is started."""
    if dep.environment.backend == "basilisk" and importlib.util.find_spec("Basilisk") is None:
        return (
            'environment.backend = "basilisk" needs Basilisk, which is not installed: install '
            "the extra with pip install -e '.[basilisk]', or set backend = \"builtin\""
        )
    return None


def open_truth(dep: Deployment) -> Truth:
    """The truth backend that ``environment.backend`` names: "builtin" or "basilisk" (the
    optional extra: pip install 'ddvi-fsw[basilisk]')."""
    if dep.environment.backend == "basilisk":
        try:
            from services.model.basilisk import BasiliskTruth
        except ImportError as exc:
            raise RuntimeError(
                f'environment.backend = "basilisk" needs Basilisk ({exc}): install the extra '
                "with pip install -e '.[basilisk]', or set backend = \"builtin\""
            ) from exc
        return BasiliskTruth(dep)
    return BuiltinTruth(dep)
