"""A run folder nobody can plant: made exclusively under the output root, with a name never
used before, private to its owner (0700) unless the operator shares it with the folder's group
(``ddvi run --folder-mode 0750``); bus.json and the credentials in it are created only new and
never through a symbolic link (``services.bus.security.write_private``).  docs/security.md,
"Run folders"."""

from __future__ import annotations

import errno
import os
from pathlib import Path

FOLDER_MODE = 0o700
"""A run folder's default mode: its owner's only."""
ATTEMPTS = 100
"""Names tried (``<run>``, ``<run>-2``, ...) before giving up on a crowded output root."""
DEPLOYMENT_FILE = "deployment.toml"
"""The deployment a run flies, copied into its folder as it starts: what ``ddvi fault`` checks
a fault against (the file the launcher read may change while the run flies)."""


def make_run_folder(root: Path, run: str, mode: int = FOLDER_MODE) -> tuple[str, Path]:
    """Create the run folder ``root/<run>`` exclusively (``root`` made if missing) and return
    (run name, folder): a name that exists already (made by anyone) is never reused, the next
    free ``<run>-<n>`` is taken instead.  Raises OSError when the root cannot hold one (not a
    folder, read-only) or no free name is found."""
    if root.exists() and not root.is_dir():
        raise NotADirectoryError(errno.ENOTDIR, "not a folder", str(root))
    root.mkdir(parents=True, exist_ok=True)
    for n in range(1, ATTEMPTS + 1):
        name = run if n == 1 else f"{run}-{n}"
        folder = root / name
        try:
            os.mkdir(folder, mode)
        except FileExistsError:  # a folder, a file or a link of that name: never used
            continue
        os.chmod(folder, mode)  # ours, just made: the umask may have taken bits off
        return name, folder
    raise FileExistsError(f"{ATTEMPTS} run names from {run!r} exist already under {root}")
