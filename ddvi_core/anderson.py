"""Anderson acceleration of value iteration, with the safeguard that keeps value iteration's
freedom from a stabilising initial gain.

Value iteration is the fixed-point iteration P <- P + eps F(P) of the Riccati flow.  Near P*
it contracts by about 1 - eps sigma per step (sigma the slowest decay of the closed loop's
Lyapunov operator, eps below the Euler limit of its fastest): on a stiff plant, whose
closed-loop rates spread by a factor s, that is about s steps per e-fold.  Anderson's method
(type II) keeps the last ``memory`` differences of iterates dX and of residuals dF and
takes the step from the combination of past iterates whose linearised residual is least:

    gamma = argmin |F_k - dF gamma|,   P_{k+1} = P_k + eps F_k - (dX + eps dF) gamma,

which on a linear map is GMRES(memory) in disguise, and cuts the s steps per e-fold to about
sqrt(s) or fewer.  The extrapolation knows nothing of the cone or of the Riccati flow's
direction far from P*, so the loop accepts its iterate only while it is symmetric positive
semidefinite, inside the current bound, and its estimated gain error (the relative stopping
rule's measure) is no larger than the one of the iterate it was extrapolated from; otherwise
it takes the plain step and forgets the history (:class:`AndersonHistory.restart`).  Every
accepted plain step is value iteration's own, so the safeguarded iteration needs no more than
value iteration does: no stabilising gain.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["DEFAULT_MEMORY", "AndersonHistory"]

DEFAULT_MEMORY = 5
"""Past differences kept: enough to span a stiff plant's few slow modes, few enough that the
small least-squares problem stays well conditioned."""

RCOND = 1e-10  # singular values of dF below this times the largest are dropped


class AndersonHistory:
    """The last ``memory`` (>= 1) differences of iterates and residuals (flattened n x n)."""

    def __init__(self, memory: int) -> None:
        if memory < 1:
            raise ValueError(f"Anderson memory must be a positive integer, got {memory}")
        self.memory = memory
        self.restart()

    def restart(self) -> None:
        """Forget the history (after a rejected extrapolation, a reset or a shorter step)."""
        self._dX: list[NDArray] = []
        self._dF: list[NDArray] = []
        self._last: tuple[NDArray, NDArray] | None = None

    def propose(self, P: NDArray, F: NDArray, eps: float) -> NDArray | None:
        """The extrapolated iterate from P (n, n) with residual F (n, n) and step eps, or None
        while there is no history (the first step after a restart is the plain one)."""
        x, f = P.ravel(), F.ravel()
        if self._last is not None:
            self._dX.append(x - self._last[0])
            self._dF.append(f - self._last[1])
            if len(self._dX) > self.memory:
                del self._dX[0], self._dF[0]
        self._last = (x.copy(), f.copy())
        if not self._dX:
            return None
        dX, dF = np.column_stack(self._dX), np.column_stack(self._dF)
        gamma = np.linalg.lstsq(dF, f, rcond=RCOND)[0]
        P_new = (x + eps * f - (dX + eps * dF) @ gamma).reshape(P.shape)
        return (P_new + P_new.T) * 0.5
