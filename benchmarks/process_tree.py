"""A process and all its descendants, read on a thread of their own while they run: the
benchmarks' peak memory of a run and CPU of each of its processes."""

from __future__ import annotations

import contextlib
import threading

import psutil


class ProcessTreeSampler:
    """Every process of a tree (``pid`` and its descendants, as they are at each read) read
    every ``period`` s until ``stop``; the first reads come sooner (0.1, 0.2, 0.4... s), so a
    run of a second is read too.  A subclass says what a read is (``read``)."""

    def __init__(self, pid: int, period: float) -> None:
        self.root = psutil.Process(pid)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._poll, args=(period,), daemon=True)
        self._thread.start()

    def read(self, processes: list[psutil.Process]) -> None:
        """One read of the tree's ``processes``, the root first (any may have just exited)."""
        raise NotImplementedError

    def _poll(self, period: float) -> None:
        wait = min(0.1, period)
        while True:
            with contextlib.suppress(psutil.Error):  # the root may have just exited
                self.read([self.root, *self.root.children(recursive=True)])
            if self._stop.wait(wait):
                return
            wait = min(2 * wait, period)

    def _end(self) -> None:
        """Stop reading, once the read under way is done."""
        self._stop.set()
        self._thread.join()
