"""The run's report as the launcher waits for it: the monitor writes it once the mission is
over (``report_wait`` s at most), and the launcher says the verdict from its summary; when
the monitor has died, the report is recovered from its recording instead (``ddvi report``),
so that a run never ends without one."""

from __future__ import annotations

import json
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

from services.config import Deployment
from services.ground.launch import lifecycle

REPORT_WAIT = 60.0  # s the monitor has for its report once the mission is over...
REPORT_WAIT_PER_DEPUTY = 5.0  # ...and this much more a deputy

Say = Callable[..., None]
"""The launcher's ``say(text, error=False)``."""


def report_wait(dep: Deployment) -> float:
    """Wall seconds the monitor has for its report once the mission is over: its series,
    figures and table grow with the deputies (32 take about a minute on a loaded 2-core
    machine)."""
    return REPORT_WAIT + REPORT_WAIT_PER_DEPUTY * len(dep.deputy)


def await_report(
    monitor: subprocess.Popen, out: Path, wait: float, started: float, say: Say
) -> int:
    """Wait for the monitor's report in the run folder ``out`` (``wait`` s at most); the
    run's exit status from its summary, said with the wall time since ``started``
    (monotonic s); the folder printed on stdout."""
    deadline = time.monotonic() + wait
    while monitor.poll() is None and time.monotonic() < deadline:
        time.sleep(0.1)  # a stop signal now changes nothing: the report is being written
    if monitor.poll() is None:
        say(f"monitor did not finish its report within {wait:g} s", error=True)
        return 1
    summary = out / "summary.json"
    if monitor.returncode != 0 or not summary.is_file():
        say(lifecycle.no_report(out, monitor.returncode), error=True)
        return 1
    took = time.monotonic() - started
    status, text = lifecycle.final_line(json.loads(summary.read_text()), out, took)
    say(text, error=status != 0)
    print(out)
    return status


def recover_report(out: Path, say: Say) -> None:
    """The monitor died: write the report from its recording in ``out``, up to the last
    complete chunk (``ddvi report``)."""
    try:
        from services.ground.analysis.recover import recover

        n = recover(out).messages
        say(f"report recovered from the recording ({n} messages); see {out}", error=True)
    except Exception as exc:  # a recovery that fails is said; the run has failed anyway
        say(f"could not recover the report ({exc}); try `ddvi report {out}`", error=True)
