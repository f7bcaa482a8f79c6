"""Relative navigation filter: a linear Kalman filter on a deputy's Hill state.

The state is ``[x, y, z, xdot, ydot, zdot]`` (m, m/s) relative to the chief, x radial, y along
track, z cross-track.  The filter propagates it with the Clohessy-Wiltshire (HCW) equations at
the chief's mean motion n, discretised exactly over the sample interval (the closed-form
transition, and Gauss-Legendre quadrature of it for the process noise), and updates it with a
measurement of the whole state (relative position and velocity, as a relative GPS solution
gives them) with white noise of known sigmas.

It knows relative-orbit kinematics and nothing else: not the atmosphere, not the craft's areas
or ballistic coefficients, not the commanded attitude.  What the HCW equations leave out, the
differential drag the controller commands, J2 and the curvature of the navigation frame, is
process noise: a white acceleration on each axis (:func:`process_noise`).  A measurement bias
is not observable from the measurement alone and passes through the filter unchanged; the
filter removes white noise only.

All functions are pure; :class:`RelativeNavFilter` holds one filter's estimate and covariance.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.polynomial.legendre import leggauss
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "DEFAULT_ACCELERATION_NOISE",
    "RelativeNavFilter",
    "hcw_matrix",
    "process_noise",
    "steady_state_covariance",
    "transition",
]

DEFAULT_ACCELERATION_NOISE = 3e-5
"""m/s^2, 1-sigma per axis of what the HCW equations leave out, averaged over a navigation
period.  The largest part is the differential drag the deputy commands with its attitude: at
300 km (rho 2.2e-11 kg/m^3, 7.73 km/s) a 0.06 m^2 facet of a 6 kg craft broadside feels
0.5 rho v^2 Cd A / m = 1.45e-5 m/s^2, against the chief's at 45 deg, so the difference spans
about +-1e-5 m/s^2 and jumps with each command; the default mission's HCW residual (the truth's
one-step prediction error) is -5e-6 m/s^2 along track on average, up to 8e-6, under 1e-6
radial and cross-track.  The filter takes it as white, so the sigma must cover its largest
value: twice that.  Over 6 orbits of the default mission's truth, 1e-6 lags behind the
commanded drag (worse than the raw measurement), 1e-5 has 1.15x (1 m of noise) and 1.6x (10 m)
the position error of 3e-5, and 1e-4 is within 10% of it at 1 and 10 m."""


def hcw_matrix(n: float) -> NDArray[np.float64]:
    """The Clohessy-Wiltshire state matrix A (6, 6) at mean motion ``n`` (rad/s):
    xddot = 3 n^2 x + 2 n ydot, yddot = -2 n xdot, zddot = -n^2 z."""
    A = np.zeros((6, 6))
    A[:3, 3:] = np.eye(3)
    A[3, 0] = 3.0 * n * n
    A[3, 4] = 2.0 * n
    A[4, 3] = -2.0 * n
    A[5, 2] = -n * n
    return A


def transition(n: float, dt: float) -> NDArray[np.float64]:
    """The HCW state transition Phi (6, 6) over ``dt`` s: x(t + dt) = Phi x(t), exact (the
    Clohessy-Wiltshire solution in closed form, the flow of :func:`hcw_matrix`)."""
    nt = n * dt
    s, c = math.sin(nt), math.cos(nt)
    Phi = np.zeros((6, 6))
    Phi[0, 0], Phi[0, 3], Phi[0, 4] = 4.0 - 3.0 * c, s / n, 2.0 * (1.0 - c) / n
    Phi[1, 0], Phi[1, 1] = 6.0 * (s - nt), 1.0
    Phi[1, 3], Phi[1, 4] = 2.0 * (c - 1.0) / n, (4.0 * s - 3.0 * nt) / n
    Phi[2, 2], Phi[2, 5] = c, s / n
    Phi[3, 0], Phi[3, 3], Phi[3, 4] = 3.0 * n * s, c, 2.0 * s
    Phi[4, 0], Phi[4, 3], Phi[4, 4] = 6.0 * n * (c - 1.0), -2.0 * s, 4.0 * c - 3.0
    Phi[5, 2], Phi[5, 5] = -n * s, c
    return Phi


def process_noise(n: float, dt: float, q: float) -> NDArray[np.float64]:
    """The process noise covariance Qd (6, 6) over ``dt`` s of a white acceleration of power
    spectral density ``q`` (m^2/s^3) on each axis:
    Qd = int_0^dt Phi(s) G q G' Phi(s)' ds with G = [0; I3] (6, 3), by Gauss-Legendre
    quadrature of the closed-form transition.  The integrand is a trigonometric polynomial
    in n s; with a node per 0.1 rad of n dt (at least 8) the quadrature is exact to rounding."""
    nodes = max(8, math.ceil(abs(n * dt) / 0.1) + 8)
    x, w = leggauss(nodes)
    Qd = np.zeros((6, 6))
    for xi, wi in zip(0.5 * dt * (x + 1.0), 0.5 * dt * w, strict=True):
        PhiG = transition(n, float(xi))[:, 3:]  # Phi(s) G
        Qd += wi * (PhiG @ PhiG.T)
    Qd *= q
    return 0.5 * (Qd + Qd.T)


def steady_state_covariance(Phi: ArrayLike, Qd: ArrayLike, R: ArrayLike) -> NDArray[np.float64]:
    """The filter's steady-state covariance after an update (6, 6), for a constant interval with
    transition Phi (6, 6), process noise Qd (6, 6) and measurement noise R (6, 6) positive
    definite (the whole state measured): the prior P- solves the discrete Riccati equation,
    and P+ = P- - P- (P- + R)^-1 P-."""
    import scipy.linalg  # here only: the navigation service never needs it (its import is costly)

    Phi, R = np.asarray(Phi, float), np.asarray(R, float)
    prior = scipy.linalg.solve_discrete_are(Phi.T, np.eye(6), np.asarray(Qd, float), R)
    return prior - prior @ np.linalg.solve(prior + R, prior)


class RelativeNavFilter:
    """A Kalman filter on the Hill state with HCW dynamics, measuring the whole state.

    Parameters
    ----------
    n : the chief's mean motion, rad/s.
    sigma : (6,) 1-sigma white measurement noise, m (position) and m/s (velocity), >= 0.
    acceleration_noise : m/s^2, 1-sigma per axis of the unmodelled acceleration averaged over
        ``period``; the white acceleration's PSD is ``acceleration_noise**2 * period``.
    period : the nominal sample interval, s (sets the PSD; other intervals are handled).

    :meth:`update` takes the measurements in time order.  The first one initialises the
    estimate (covariance R).  A component measured without noise is published as measured,
    exactly: with every sigma zero the filter is the identity, bit for bit.
    """

    def __init__(
        self,
        n: float,
        sigma: ArrayLike,
        acceleration_noise: float = DEFAULT_ACCELERATION_NOISE,
        period: float = 10.0,
    ) -> None:
        self.n = float(n)
        self.sigma = np.asarray(sigma, dtype=float).reshape(6)
        if not (np.isfinite(self.sigma).all() and (self.sigma >= 0).all()):
            raise ValueError(f"measurement sigmas must be finite and >= 0, got {self.sigma}")
        if not (math.isfinite(acceleration_noise) and acceleration_noise > 0):
            raise ValueError(f"acceleration_noise must be > 0 m/s^2, got {acceleration_noise}")
        if not (math.isfinite(period) and period > 0):
            raise ValueError(f"period must be > 0 s, got {period}")
        self.q = acceleration_noise**2 * period
        self.R = np.diag(self.sigma**2)
        self.exact = self.sigma == 0.0  # components published as measured
        self.t: float | None = None
        self.x = np.zeros(6)
        self.P = np.zeros((6, 6))
        self._models: dict[float, tuple[NDArray, NDArray]] = {}

    def _model(self, dt: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Phi and Qd over dt, cached per interval (a run has one or two)."""
        key = round(dt, 6)
        if key not in self._models:
            self._models[key] = (transition(self.n, key), process_noise(self.n, key, self.q))
        return self._models[key]

    def update(self, t: float, z: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Take the measurement z (6,) at time t (s, after the previous one); returns the
        estimate (6,) and its covariance (6, 6) (m^2, m^2/s, m^2/s^2)."""
        z = np.asarray(z, dtype=float)
        if self.exact.all():  # nothing to filter: the identity, exactly
            self.t, self.x, self.P = t, z, np.zeros((6, 6))
            return self.x, self.P
        if self.t is None:
            x, P = z.copy(), self.R.copy()
        else:
            Phi, Qd = self._model(t - self.t)
            x, P = Phi @ self.x, Phi @ self.P @ Phi.T + Qd
            K = np.linalg.solve(P + self.R, P).T  # P (P + R)^-1, both symmetric
            x = x + K @ (z - x)
            IK = np.eye(6) - K
            P = IK @ P @ IK.T + K @ self.R @ K.T  # Joseph form: stays symmetric PSD
            P = 0.5 * (P + P.T)
        x[self.exact] = z[self.exact]
        self.t, self.x, self.P = t, x, P
        return x, P

    def predict(self, t: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """Propagate the estimate to time t (s, after the previous one) with no measurement (an
        outage): returns the prediction (6,) and its covariance (6, 6), which grows by the
        process noise.  The next :meth:`update` starts from it."""
        if self.t is None:
            raise ValueError("predict: no measurement yet to propagate")
        Phi, Qd = self._model(t - self.t)
        x, P = Phi @ self.x, Phi @ self.P @ Phi.T + Qd
        self.t, self.x, self.P = t, x, 0.5 * (P + P.T)
        return self.x, self.P
