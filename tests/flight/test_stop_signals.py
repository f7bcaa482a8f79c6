"""A service's stop signals (``services.flight.runtime.stop_on_signals``): a signal sets the
stop request even when it comes while the main thread holds the request's lock, as a second
signal does in the middle of the first one's ``Event.set``."""

from __future__ import annotations

import subprocess
import sys
import textwrap

CHILD = textwrap.dedent(
    """
    import os, signal, threading, time
    from services.flight.runtime import stop_on_signals

    stop = threading.Event()
    stop_on_signals(stop)
    # a signal while this thread holds the Event's lock: a handler that set the Event itself
    # would wait on that lock forever
    with stop._cond:
        os.kill(os.getpid(), signal.SIGTERM)
        os.kill(os.getpid(), signal.SIGHUP)
        time.sleep(0.2)
    print("stopped" if stop.wait(5) else "not stopped", flush=True)
    """
)


def test_a_stop_signal_while_the_stop_request_is_locked_still_stops() -> None:
    done = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, timeout=30)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "stopped"
