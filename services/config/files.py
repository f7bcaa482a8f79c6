"""Deployment files: finding one by name or path, reading, writing and loading it.

Named deployments live in the repository's ``deployments/`` folder; an installed package
carries the same files (the wheel's data files, ``<prefix>/share/ddvi-fsw/deployments``), so
``ddvi run`` finds them without a source checkout.  :func:`resolve` looks in the source tree
first, then in the installed location; so do :func:`campaign_file` (``deployments/campaigns``)
and :func:`system_example` (``docs/examples/systems``, installed the same way).
"""

from __future__ import annotations

import copy
import difflib
import sysconfig
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING, Any

from services.config.deployment import Deployment, DeploymentError
from services.config.validation import deployment_from_table

if TYPE_CHECKING:
    from ddvi_core.systems import System

__all__ = [
    "DEPLOYMENTS_DIR",
    "campaign_file",
    "deployment_dirs",
    "load_deployment",
    "load_system",
    "read_table",
    "resolve",
    "system_example",
    "with_ros2",
    "write_deployment",
]

DEFAULT_DEPLOYMENT = "rendezvous"

DEPLOYMENTS_DIR = Path(__file__).resolve().parents[2] / "deployments"
"""The source tree's deployments/ folder (present in a checkout or an editable install)."""

INSTALLED_SUBDIR = Path("share", "ddvi-fsw", "deployments")
"""Where an installed package's data files put the named deployments, under a scheme's data
directory (pyproject.toml, ``[tool.setuptools.data-files]``)."""


def deployment_dirs() -> list[Path]:
    """The folders that hold named deployments, in search order: the source tree's, then the
    installed package's (the interpreter's prefix, then the user scheme); only those that
    exist."""
    candidates = [DEPLOYMENTS_DIR]
    for scheme in (sysconfig.get_default_scheme(), sysconfig.get_preferred_scheme("user")):
        candidates.append(Path(sysconfig.get_path("data", scheme)) / INSTALLED_SUBDIR)
    found: list[Path] = []
    for folder in candidates:
        if folder.is_dir() and folder.resolve() not in found:
            found.append(folder.resolve())
    return found


def shared_dirs(relative: str) -> list[Path]:
    """The folders of the repository's ``relative`` (``docs/examples/systems``) in search
    order: the source tree's, then the installed package's data files (share/ddvi-fsw/...);
    only those that exist."""
    candidates = [DEPLOYMENTS_DIR.parent / relative]
    for scheme in (sysconfig.get_default_scheme(), sysconfig.get_preferred_scheme("user")):
        candidates.append(Path(sysconfig.get_path("data", scheme)) / "share/ddvi-fsw" / relative)
    found: list[Path] = []
    for folder in candidates:
        if folder.is_dir() and folder.resolve() not in found:
            found.append(folder.resolve())
    return found


def _shipped(name_or_path: str, folders: list[Path]) -> Path | None:
    """A file by path, else by its name (or its path's file name) in the first of ``folders``
    that has it: ``rendezvous-200`` and ``deployments/campaigns/rendezvous-200.toml`` from any
    working directory."""
    p = Path(name_or_path)
    if p.is_file():
        return p
    stem = p.name.removesuffix(".toml")
    return next((f / f"{stem}.toml" for f in folders if (f / f"{stem}.toml").is_file()), None)


def campaign_file(name_or_path: str) -> Path | None:
    """A campaign file by path, or a shipped one by name (``rendezvous-200``); None if none."""
    return _shipped(name_or_path, [d / "campaigns" for d in deployment_dirs()])


def system_example(name_or_path: str) -> Path | None:
    """A system file by path, or a shipped example by name (``cart-pole``); None if none."""
    return _shipped(name_or_path, shared_dirs("docs/examples/systems"))


def load_system(name_or_path: str) -> System:
    """A built-in scenario by name, a shipped example by name (``cart-pole``), or a system
    file (TOML) by path; SystemFileError names what is wrong."""
    # the mathematics (scipy) only for a command that learns: `ddvi fault` reads deployments
    from ddvi_core.systems import BUILTIN_SYSTEMS, SystemFileError, system_from_table

    if name_or_path in BUILTIN_SYSTEMS:
        return BUILTIN_SYSTEMS[name_or_path]()
    path = system_example(name_or_path)
    if path is None or not path.is_file():
        folders = shared_dirs("docs/examples/systems")
        examples = sorted({f.stem for folder in folders for f in folder.glob("*.toml")})
        # a path is matched by its file's name: docs/examples/cartpole.toml -> cart-pole,
        # which any folder finds by that name
        stem = Path(name_or_path).name.removesuffix(".toml")
        close = difflib.get_close_matches(stem, [*BUILTIN_SYSTEMS, *examples], n=1)
        hint = f" (did you mean '{close[0]}'?)" if close else ""
        raise SystemFileError(
            f"{name_or_path}: no such built-in scenario, example or file{hint}; give a "
            f"built-in ({', '.join(BUILTIN_SYSTEMS)}), an example by its name "
            + (f"({', '.join(examples)}) " if examples else "")
            + "or a system file's path"
        )
    try:
        table = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise SystemFileError(f"{path}: not valid TOML ({exc})") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise SystemFileError(f"{path}: cannot be read ({exc})") from None
    return system_from_table(table, default_name=path.stem)


def resolve(name_or_path: str | None) -> Path:
    """A deployment file by path, or by name (``rendezvous`` when None) in the first of
    :func:`deployment_dirs` that has it."""
    if name_or_path is None:
        name_or_path = DEFAULT_DEPLOYMENT
    p = Path(name_or_path)
    if p.is_file():
        return p
    folders = deployment_dirs()
    for folder in folders:
        q = folder / f"{name_or_path}.toml"
        if q.is_file():
            return q
    known = sorted({x.stem for folder in folders for x in folder.glob("*.toml")})
    if p.is_dir():
        raise DeploymentError(
            f"{name_or_path}: is a directory, not a deployment file; give a .toml file in it "
            "or a deployment name; known: " + ", ".join(known)
        )
    near = difflib.get_close_matches(name_or_path, known, n=1)
    hint = f" (did you mean '{near[0]}'?)" if near else ""
    raise DeploymentError(
        f"{name_or_path}: no such deployment file or name{hint}; known: " + ", ".join(known)
    )


def read_table(name_or_path: str | None) -> dict[str, Any]:
    """A deployment file's raw TOML table (to derive another deployment from it)."""
    return tomllib.loads(resolve(name_or_path).read_text())


def write_deployment(table: dict[str, Any], folder: Path, name: str) -> Path:
    """Write a deployment table to ``folder/name.toml``, its runs going under ``folder/runs``
    (benchmarks and sweeps derive their deployments this way)."""
    import tomli_w

    table = copy.deepcopy(table)
    table.setdefault("run", {})["output"] = str(folder / "runs")
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.toml"
    path.write_bytes(tomli_w.dumps(table).encode())
    return path


def load_deployment(name_or_path: str | None) -> Deployment:
    """The checked Deployment of a file by name or path (see :func:`resolve`)."""
    path = resolve(name_or_path)
    return deployment_from_table(_read(path), str(path))


def with_ros2(
    name_or_path: str | None, endpoint: str | None = None
) -> tuple[Deployment, dict[str, Any]]:
    """The deployment of a file (see :func:`resolve`) with its ROS 2 gateway on (``ddvi run
    --ros2 [ENDPOINT]``), at ``endpoint`` (None: its ``[ros2]`` table's), checked, and its
    table: what the run folder keeps as the deployment the run flies."""
    path = resolve(name_or_path)
    table = _read(path)
    ros2 = table.setdefault("ros2", {})
    if not isinstance(ros2, dict):
        raise DeploymentError(f"ros2: expected a table, got {ros2!r}")
    ros2["enabled"] = True
    if endpoint is not None:
        ros2["endpoint"] = endpoint
    return deployment_from_table(table, str(path)), table


def _read(path: Path) -> dict[str, Any]:
    """The TOML table of the deployment file ``path``; DeploymentError saying why not."""
    try:
        table = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise DeploymentError(f"{path}: not valid TOML ({exc})") from None
    except UnicodeDecodeError as exc:  # a binary file, or text in another encoding
        raise DeploymentError(
            f"{path}: not a UTF-8 text file (byte {exc.start}: {exc.reason}); a deployment "
            "is TOML text"
        ) from None
    except OSError as exc:
        raise DeploymentError(f"{path}: cannot read it ({exc.strerror})") from None
    return table
