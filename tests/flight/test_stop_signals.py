"""A service's stop signals (``services.flight.runtime.stop_on_signals``): a signal sets the
stop request even when it comes while the main thread holds the request's lock, as a second
signal does in the middle of the first one's ``Event.set``."""

from __future__ import annotations

import subprocess
import sys
import textwrap

CHILD = textwrap.dedent(
    """
    import os, signal, sys, threading, time
    from services.flight.runtime import stop_on_signals

    stop = threading.Event()
    stop_on_signals(stop)
    (relay,) = [t for t in threading.enumerate() if t.name == "stop-signals"]

    def relay_in_set():  # it has read a signal's byte and waits for the lock held here
        frame = sys._current_frames().get(relay.ident)
        while frame is not None:
            if frame.f_code is threading.Event.set.__code__:
                return True
            frame = frame.f_back
        return False

    # a signal while this thread holds the Event's lock: a handler that set the Event itself
    # would wait on that lock forever
    with stop._cond:
        os.kill(os.getpid(), signal.SIGTERM)
        os.kill(os.getpid(), signal.SIGHUP)
        # hold the lock until the stop is on its way (the handlers ran; the relay waits)
        deadline = time.monotonic() + 20
        while not relay_in_set():
            if time.monotonic() > deadline:
                print("the relay never tried to set the stop", flush=True)
                os._exit(1)
            time.sleep(0.01)
    print("stopped" if stop.wait(5) else "not stopped", flush=True)
    """
)


def test_a_stop_signal_while_the_stop_request_is_locked_still_stops() -> None:
    done = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, timeout=30)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "stopped"
