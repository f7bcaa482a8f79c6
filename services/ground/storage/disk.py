"""The run folder's disk: how much is left on it, and files written whole or not at all.

A run writes its recording, its report and its logs into one folder, whose disk may fill (a
small partition, a quota, another process) or fail.  The recording closes itself whole while
its ``Recorder.room()`` is still left, so that the report keeps ``REPORT_ROOM``
(``services.ground.storage.recording``: ``RecordFile`` is its file); the report writes its
timeseries and figures only into what is left beyond that room, and each of its files whole or not
at all (``write_whole``): a file that did not fit is not there, and the report names it.  A failure
is one line naming the file, why, and the space left (``failure``); a log file that cannot be
written loses its lines, said once (``LogFile``).
"""

from __future__ import annotations

import contextlib
import errno
import logging
import os
import sys
from pathlib import Path
from typing import Any

REPORT_ROOM = 256 * 1024
"""Bytes kept for summary.json and report.md (a few tens of KB; more with many services)."""
PART = ".part"
"""The suffix of a file being written; renamed to its name once whole, removed if not."""


def space_left(where: Path | int) -> int | None:
    """Bytes an unprivileged user may still write on the file system of ``where`` (a path, or
    an open file's descriptor); None when it cannot be told."""
    try:
        st = os.fstatvfs(where) if isinstance(where, int) else os.statvfs(where)
    except OSError:
        return None
    return st.f_bavail * st.f_frsize


def size_text(n: int | None) -> str:
    """``n`` bytes for a person: "0 B", "412 KB", "1.3 MB", "2.1 GB" (decimal units)."""
    if n is None:
        return "an unknown amount"
    for unit, scale in (("GB", 1e9), ("MB", 1e6), ("KB", 1e3)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{n} B"


def failure(path: Path, exc: OSError | str) -> str:
    """One line for a write of ``path`` that failed: why, and the space left on its disk."""
    why = exc if isinstance(exc, str) else (exc.strerror or str(exc))
    return f"{path}: {why} ({size_text(space_left(path.parent))} left on {path.parent})"


def no_room(path: Path, size: int, keep: int) -> OSError:
    """The error of a write of ``size`` bytes refused before it began, ``keep`` bytes being
    kept free for the report."""
    kept = f" and the {size_text(keep)} kept for the report" if keep else ""
    return OSError(errno.ENOSPC, f"no room for its {size_text(size)}{kept}", str(path))


def write_whole(path: Path, data: bytes, keep: int = 0) -> None:
    """Write ``data`` as ``path``, whole or not at all: raises OSError (ENOSPC when fewer than
    ``len(data) + keep`` bytes are left on its disk, or whatever the write raised) and leaves
    neither a part of it nor a changed ``path`` behind."""
    left = space_left(path.parent)
    if left is not None and left < len(data) + keep:
        raise no_room(path, len(data), keep)
    part = path.with_name(path.name + PART)
    try:
        with part.open("wb") as f:
            f.write(data)
        part.replace(path)
    except OSError:
        part.unlink(missing_ok=True)
        raise


CHUNK = 0x06  # the MCAP opcode of a chunk record


class RecordFile:
    """The file an MCAP writer writes records into, unbuffered: each ``write`` (whole records)
    reaches the OS whole or raises OSError.  ``whole`` is the file's size at the end of the
    last write that did (a record boundary, what ``cut`` truncates back to), ``chunks`` how many
    chunk records went whole, and ``left`` the space left on its disk after the last write."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.file = path.open("wb", buffering=0)
        self.position = self.whole = self.chunks = 0
        self.left = space_left(self.file.fileno())

    def write(self, data: bytes) -> int:
        view = memoryview(data)
        while view:
            n = self.file.write(view)
            if not n:  # a full disk may take part of a write, then nothing
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(self.path))
            self.position += n
            view = view[n:]
        self.whole = self.position
        self.chunks += data[:1] == bytes([CHUNK])
        self.left = space_left(self.file.fileno())
        return len(data)

    def tell(self) -> int:
        return self.position

    def flush(self) -> None:
        """Nothing is buffered here: every write went to the OS."""

    def sync(self) -> None:
        os.fsync(self.file.fileno())

    def cut(self) -> None:
        """Truncate the file back to the end of its last whole write (a failed write leaves
        part of a record after it) and close it; what is left reads as a recording cut short."""
        try:
            os.ftruncate(self.file.fileno(), self.whole)
        finally:
            self.file.close()

    def close(self) -> None:
        self.file.close()


class LogFile(logging.StreamHandler[Any]):
    """A log handler on a stream whose file may sit on a full or failing disk: a line it cannot
    write is lost, and said once on stderr (one line, never logging's traceback)."""

    def __init__(self, stream: Any) -> None:
        super().__init__(stream)
        self.failed = False

    def handleError(self, record: logging.LogRecord) -> None:
        if self.failed:
            return
        self.failed = True
        exc = sys.exc_info()[1]
        why = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        name = getattr(self.stream, "name", "the log file")
        with contextlib.suppress(OSError, ValueError):
            sys.stderr.write(
                f"cannot write the log {name} ({why}): its lines from here on are lost\n"
            )
