"""On-station trim of a learned feedforward: the model-fit learner's slow outer loop.

Along track the dynamics do not see where the deputy is (no point of a circular orbit is
special), so the learned gain holds the slot only through K_y = sqrt(Q_yy / R), about 3.7e-4
rad/m: a feedforward that is off by 0.004 rad, a few percent of the drag offset it cancels,
holds the deputy 10 m off the slot.  A fitted drag offset is not that accurate (it is fitted
far behind the slot, on noisy data), but the mean along-track estimate over an orbit is: the
navigation noise averages over hundreds of samples.  So once the deputy is on station, every
``period`` seconds the controller moves the feedforward's constant term by
``-gain * K_y * mean(y - y_ref)`` over the period: an integral action, updated once per
period on the period's mean, that leaves the fitted K and the exostate's harmonics alone.

The period should be at least the closed loop's along-track time constant (about 1.2 orbits
for the default mission's LQR gains), so that each mean sees the last correction settled;
``gain`` < 1 keeps the loop from overshooting while it has not.  (Trimming the orbit-rate
terms the same way, through the closed loop's response at the orbit rate, was tried and
diverges: over two orbits the forced orbit-rate response cannot be told from the loop's own
lightly damped mode at nearly that frequency.)
"""

from __future__ import annotations

import math

import numpy as np


class StationTrim:
    """The trim's state: the along-track errors of the current period and the total trim.

    ``period`` (s) between updates, ``radius`` (m): a period counts as on station only when
    every |y - y_ref| in it is at most this (the approach is a transient, not a bias);
    ``gain`` (0, 1] of each update; ``start`` (s): samples before it are ignored."""

    def __init__(self, period: float, radius: float, gain: float, start: float) -> None:
        if not (period > 0 and radius > 0 and 0 < gain <= 1 and math.isfinite(start)):
            raise ValueError(
                f"trim needs period > 0 s, radius > 0 m, gain in (0, 1], a finite start; got "
                f"{period}, {radius}, {gain}, {start}"
            )
        self.period, self.radius, self.gain = float(period), float(radius), float(gain)
        self.next_update = start + self.period
        self.errors: list[float] = []
        self.total = 0.0  # the feedforward's constant term moved by this so far (rad)

    def restart(self, t: float) -> None:
        """The feedforward was replaced at t (a refit): no trim in it, and the period's
        errors, flown before, dropped; the next update a period from t."""
        self.total, self.errors, self.next_update = 0.0, [], t + self.period

    def add(self, t: float, error: float) -> None:
        """One navigation sample's along-track error y - y_ref (m) at t (s)."""
        if t >= self.next_update - self.period - 1e-6 and math.isfinite(error):
            self.errors.append(float(error))

    def due(self, t: float) -> bool:
        return t >= self.next_update - 1e-6

    def update(self, t: float, K_y: float) -> tuple[float, str]:
        """At a due step t, with the gain's along-track term K_y (rad/m): the change (rad) to
        add to the feedforward's constant term, and the log line; the period's errors are
        dropped either way."""
        errors, self.errors = np.asarray(self.errors), []
        self.next_update = t + self.period
        if errors.size == 0:
            return 0.0, f"station trim at t = {t:.0f} s: no samples, not moved"
        worst = float(np.max(np.abs(errors)))
        if worst > self.radius:
            return 0.0, (
                f"station trim at t = {t:.0f} s: not on station (|y - y_ref| up to {worst:.1f} m "
                f"> {self.radius:g} m), not moved"
            )
        mean = float(np.mean(errors))
        delta = -self.gain * K_y * mean
        self.total += delta
        return delta, (
            f"station trim at t = {t:.0f} s: mean along-track error {mean:+.2f} m over "
            f"{errors.size} samples, feedforward constant moved by {delta:+.3g} rad "
            f"(total {self.total:+.3g})"
        )
