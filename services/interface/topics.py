"""Topic names below ``ddvi/<run>/``: one function (or constant) builds each, so no service
spells a topic by hand.

A deputy's or a service's name is one key chunk (``check_name`` in the bus refuses ``/`` and
wildcards), so each function below returns a key with no wildcards.
"""

from __future__ import annotations

CLOCK = "clock"
"""The environment's simulation clock (``final = true`` ends the mission)."""

EXOSTATE = "exo/state"
"""The exosystem state v(t) the controllers regulate against."""


def truth_topic(craft: str) -> str:
    """``truth/<craft>``: the environment's inertial state of one craft (chief or deputy)."""
    return f"truth/{craft}"


def nav_state_topic(deputy: str) -> str:
    """``nav/<deputy>/state``: navigation's relative Hill state of one deputy."""
    return f"nav/{deputy}/state"


def command_topic(deputy: str) -> str:
    """``cmd/<deputy>/att``: a controller's attitude command for one deputy."""
    return f"cmd/{deputy}/att"


def gains_topic(deputy: str) -> str:
    """``ctrl/<deputy>/gains``: the gains (K, L) a deputy's controller flies."""
    return f"ctrl/{deputy}/gains"


def status_topic(deputy: str) -> str:
    """``ctrl/<deputy>/status``: a controller's mode, phase and learning progress."""
    return f"ctrl/{deputy}/status"


def fault_topic(kind: str) -> str:
    """``fault/<kind>``: a fault the ground injects (kill, panel, bias, link)."""
    return f"fault/{kind}"


def stats_topic(service: str) -> str:
    """``stats/<service>``: a service's counters (received, rejected, late, ...)."""
    return f"stats/{service}"


def log_topic(service: str) -> str:
    """``log/<service>``: a service's log lines, for the ground."""
    return f"log/{service}"


def alive_topic(service: str) -> str:
    """``alive/<service>``: a service's liveliness token (a zenoh liveliness key, no payload)."""
    return f"alive/{service}"
