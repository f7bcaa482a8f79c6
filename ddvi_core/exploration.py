"""Exploration signals for the data of a system file, and the state that starts them on their
periodic response.

:class:`InterleavedExploration` gives each input its own frequencies, so inputs that drive
alike subsystems (a quadrotor's roll and pitch) leave different signatures in the data.
:func:`periodic_start` is the initial state on the exploration's periodic response: started
there, a plant with integrators (a double integrator, a quadrotor's position) does not drift
polynomially away, which would make its states collinear in the data.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from ddvi_core.simulate import Exploration

__all__ = ["InterleavedExploration", "periodic_start"]


@dataclass(frozen=True)
class InterleavedExploration(Exploration):
    """Input i sums (amplitude / count_i) sin(w_f t + phi_f) over the frequencies
    f = i, i + m, i + 2m, ... of ``frequencies`` (count_i of them), phases from ``seed``;
    |eta_i| never exceeds ``amplitude``."""

    def phasors(self, m: int) -> tuple[NDArray, NDArray]:
        """(w (k,), c (k, m)): input i is sum_f Im(c_fi e^{j w_f t}) (computed once per m)."""
        cache = self.__dict__.setdefault("_phasor_cache", {})
        if m not in cache:
            cache[m] = self._compute_phasors(m)
        return cache[m]

    def _compute_phasors(self, m: int) -> tuple[NDArray, NDArray]:
        w = np.asarray(self.frequencies, dtype=float)
        phases = np.random.default_rng(self.seed).uniform(0, 2 * np.pi, size=w.size)
        c = np.zeros((w.size, m), dtype=complex)
        for i in range(m):
            mine = np.arange(i, w.size, m)
            if mine.size:
                c[mine, i] = self.amplitude / mine.size * np.exp(1j * phases[mine])
        return w, c

    def __call__(self, t: float, m: int) -> NDArray[np.float64]:
        if not self.frequencies or self.amplitude == 0:
            return np.zeros(m)
        w, c = self.phasors(m)
        return (np.exp(1j * w * t) @ c).imag


def periodic_start(A: NDArray, B: NDArray, exploration: Exploration) -> NDArray[np.float64]:
    """x0 (n,) on the periodic response of x' = A x + B eta(t) to ``exploration`` (an
    :class:`InterleavedExploration`; zeros for another kind): sum_f Im((j w_f I - A)^-1 B c_f),
    A (n, n) the closed loop under K0, B (n, m).  The zero-order hold of the input leaves a
    drift of relative size w dt, which the data tolerate."""
    n, m = B.shape
    if not isinstance(exploration, InterleavedExploration) or not exploration.frequencies:
        return np.zeros(n)
    w, c = exploration.phasors(m)
    x0 = np.zeros(n, dtype=complex)
    for wf, cf in zip(w, c, strict=True):
        try:
            x0 += np.linalg.solve(1j * wf * np.eye(n) - A, B @ cf)
        except np.linalg.LinAlgError:
            continue  # the exploration sits on an eigenvalue: no periodic response there
    return x0.imag
