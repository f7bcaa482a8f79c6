"""Would a Rauch-Tung-Striebel smoother let the paper's value iteration learn ``realistic-nav``?

The ``realistic-nav`` value-iteration deputy ("ddvi") alone, flown in process to its learning
attempt (orbit 15, from the last 12 orbits) through the Kalman filter, recording what the
learner collects (t, x, u, v) and the filter's forward pass (prediction, update, transition).
The same learning attempt (``ValueIterationLearner.learn`` on a fresh ``IntervalCollector``
with the deployment's settings, the window the flight attempt used) is then run on the same
u, v with x from:

- ``filtered``: the flight's estimate (must reproduce the flight attempt's outcome);
- ``smoothed``: a full-batch RTS pass over the filter's forward pass up to the attempt (the
  upper bound of any fixed-lag smoother);
- ``lag N``: a fixed-lag RTS smoother, x(t_k | t_{k+N}) (N samples of 10 s);
- ``truth``: the deputy's true relative state in navigation's frame (the ceiling).

Run: ``python -m benchmarks.rts_smoother [--noise 1.0 0.5] [--draws 3] [--lags 6 30 60]``;
velocity noise 1e-3 /s x position noise as the deployment.  One process.
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import time

import numpy as np

from ddvi_core.lqr import relative_gain_error
from ddvi_core.navfilter import RelativeNavFilter, process_noise, transition
from services.config import deployment_from_table, read_table
from services.flight import learners as learners_mod
from services.flight.inprocess import run_in_process
from services.model import IN_PLANE, true_lqr_gains

DEPLOYMENT = os.environ.get("RTS_DEPLOYMENT", "realistic-nav")
LEARNER = "ddvi"
PLANE = list(IN_PLANE)


def _model(f: RelativeNavFilter, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The filter's transition and discrete process noise over dt, as its update takes them."""
    dt = round(dt, 6)
    return transition(f.n, dt), process_noise(f.n, dt, f.q)


def _recorded_update(update, f: RelativeNavFilter, t: float, z: np.ndarray) -> tuple:
    """``update(f, t, z)`` and what the RTS pass needs of it: ((x, P) as update returns
    them, (t, Phi (None first), x_pred, P_pred, x_f, P_f))."""
    if f.t is None:
        Phi = xp = Pp = None
    else:
        Phi, Qd = _model(f, t - f.t)
        xp, Pp = Phi @ f.x, Phi @ f.P @ Phi.T + Qd
    x, P = update(f, t, z)
    return (x, P), (t, Phi, xp, Pp, x.copy(), P.copy())


class Recorder:
    """Wraps RelativeNavFilter.update and ValueIterationLearner.collect / attempt."""

    def __init__(self) -> None:
        self.nav: list[tuple] = []  # t, Phi (None first), x_pred, P_pred, x_f, P_f
        self.samples: list[tuple] = []  # t, x (4,), u, v
        self.attempts: list[tuple] = []  # since, exosystem, Attempt
        self._orig = (
            RelativeNavFilter.update,
            learners_mod.ValueIterationLearner.collect,
            learners_mod.ValueIterationLearner.attempt,
        )

    def __enter__(self) -> Recorder:
        update, collect, attempt = self._orig
        rec = self

        def update_w(f, t, z):
            estimate, record = _recorded_update(update, f, t, z)
            rec.nav.append(record)
            return estimate

        def collect_w(lr, t, x, u, v):
            rec.samples.append((t, np.array(x, float), float(u), np.array(v, float)))
            return collect(lr, t, x, u, v)

        def attempt_w(lr, since, exosystem, due):
            a = attempt(lr, since, exosystem, due)
            rec.attempts.append((since, exosystem, a, lr, len(rec.samples)))
            return a

        RelativeNavFilter.update = update_w
        learners_mod.ValueIterationLearner.collect = collect_w
        learners_mod.ValueIterationLearner.attempt = attempt_w
        return self

    def __exit__(self, *exc) -> None:
        (
            RelativeNavFilter.update,
            learners_mod.ValueIterationLearner.collect,
            learners_mod.ValueIterationLearner.attempt,
        ) = self._orig


def rts_gains(nav: list[tuple]) -> tuple[np.ndarray, ...]:
    """Forward pass arrays and the RTS gains C_k = P_f[k] Phi_{k+1}' P_pred[k+1]^-1."""
    t = np.array([r[0] for r in nav])
    xf = np.array([r[4] for r in nav])
    Pf = np.array([r[5] for r in nav])
    N = len(nav)
    xp = np.zeros_like(xf)
    Pp = np.zeros_like(Pf)
    C = np.zeros_like(Pf)
    for k in range(1, N):
        _, Phi, xp[k], Pp[k], _, _ = nav[k]
        C[k - 1] = np.linalg.solve(Pp[k], Phi @ Pf[k - 1]).T  # Pf Phi' Pp^-1 (Pp symmetric)
    return t, xf, Pf, xp, Pp, C


def forward(
    t: np.ndarray,
    z: np.ndarray,
    n: float,
    sigma: list[float],
    accel: float,
    period: float,
) -> tuple[np.ndarray, ...]:
    """The navigation filter's forward pass over measurements z (K, 6) at t (K,), with
    acceleration noise ``accel`` (what the flight filter does, retuned): arrays as rts_gains."""
    f = RelativeNavFilter(n, sigma, accel, period)
    update = RelativeNavFilter.update
    return rts_gains([_recorded_update(update, f, tk, zk)[1] for tk, zk in zip(t, z, strict=True)])


def rts_full(
    xf: np.ndarray, Pf: np.ndarray, xp: np.ndarray, Pp: np.ndarray, C: np.ndarray, end: int
) -> tuple[np.ndarray, np.ndarray]:
    """Full-batch RTS over samples 0..end (inclusive)."""
    xs, Ps = xf[: end + 1].copy(), Pf[: end + 1].copy()
    for k in range(end - 1, -1, -1):
        xs[k] = xf[k] + C[k] @ (xs[k + 1] - xp[k + 1])
        Ps[k] = Pf[k] + C[k] @ (Ps[k + 1] - Pp[k + 1]) @ C[k].T
    return xs, Ps


def rts_lag(xf: np.ndarray, xp: np.ndarray, C: np.ndarray, lag: int, end: int) -> np.ndarray:
    """Fixed-lag smoother: x(k | min(k + lag, end)) for k = 0..end (RTS from k + lag)."""
    n = end + 1
    k = np.arange(n)
    top = np.minimum(k + lag, end)
    s = xf[top].copy()
    for j in range(lag - 1, -1, -1):
        idx = k + j
        act = idx < top  # only steps inside [k, top)
        i = idx[act]
        s[act] = xf[i] + np.einsum("kij,kj->ki", C[i], s[act] - xp[i + 1])
    return s


def relearn(
    learner: learners_mod.ValueIterationLearner,
    samples: list[tuple],
    xs: np.ndarray,
    since: float,
    exosystem: tuple,
) -> learners_mod.Attempt:
    """The flight attempt on a fresh store fed (t, xs[i], u, v)."""
    saved = learner.store
    learner.store = learner.new_store(saved.q)
    try:
        for (t, _, u, v), x in zip(samples, xs, strict=True):
            learner.store.add(t, x, [u], v)
        return learner.attempt(since, exosystem, 0.0)
    finally:
        learner.store = saved


def draw(noise: float, seed: int, lags: list[int], accels: list[float]) -> dict:
    """Draw ``seed`` at ``noise`` m: the flight attempt's outcome and, per source of the state
    (see the module), (learned, gain error or None, why refused, the RMS error (4,) of the
    learning window's states against the truth)."""
    table = read_table(DEPLOYMENT)
    table["deputy"] = [d for d in table["deputy"] if d["name"] == LEARNER]
    (deputy,) = table["deputy"]
    deputy["navigation"].update(position_noise=noise, velocity_noise=1e-3 * noise)
    deputy["learning"]["seed"] = seed
    table["run"]["seed"] = seed
    table["run"]["orbits"] = deputy["learning"]["learn_at_orbits"] + 0.02
    dep = deployment_from_table(table)
    with Recorder() as rec:
        out = run_in_process(dep)[LEARNER]
    K_star = np.asarray(true_lqr_gains(dep, dep.deputy_named(LEARNER))[0])
    (since, exosystem, flight, learner, n_seen) = rec.attempts[0]
    rec.samples = rec.samples[:n_seen]  # what the flight attempt had
    t_nav, xf, Pf, xp, Pp, C = rts_gains(rec.nav)
    ts = np.array([s[0] for s in rec.samples])
    # the nav sample of each collected sample, and the last nav sample the attempt could see
    idx = np.searchsorted(t_nav, ts - 1e-6)
    assert np.allclose(t_nav[idx], ts)
    assert np.allclose(xf[idx][:, PLANE], [s[1] for s in rec.samples])
    end = int(idx[-1])
    truth = np.asarray(out["x"])[idx][:, PLANE]
    assert np.allclose(np.asarray(out["t"])[idx], ts)
    xs, _ = rts_full(xf, Pf, xp, Pp, C, end)
    variants = {
        "filtered": np.array([s[1] for s in rec.samples]),
        "smoothed": xs[idx][:, PLANE],
        **{f"lag {L}": rts_lag(xf, xp, C, L, end)[idx][:, PLANE] for L in lags},
    }
    # navigation retuned: the same measurements through a filter with less process noise
    nav_cfg = dep.deputy_named(LEARNER).navigation
    sigma = [nav_cfg.position_noise] * 3 + [nav_cfg.velocity_noise] * 3
    n_rate = rec.attempts[0][3].n_rate
    z_all = np.asarray(out["z"])
    for q in accels:
        _, xf2, Pf2, xp2, Pp2, C2 = forward(
            t_nav[: end + 1], z_all[: end + 1], n_rate, sigma, q, nav_cfg.period
        )
        xs2, _ = rts_full(xf2, Pf2, xp2, Pp2, C2, end)
        variants[f"filtered q={q:g}"] = xf2[idx][:, PLANE]
        variants[f"smoothed q={q:g}"] = xs2[idx][:, PLANE]
        for L in lags:
            variants[f"lag {L} q={q:g}"] = rts_lag(xf2, xp2, C2, L, end)[idx][:, PLANE]
    variants["truth"] = truth
    res = {"noise": noise, "seed": seed, "flight": flight.refused or "learned"}
    win = ts >= since - 1e-6
    for name, x in variants.items():
        a = relearn(learner, rec.samples, x, since, exosystem)
        err = x[win] - truth[win]
        rms = np.sqrt((err**2).mean(axis=0))
        learned = a.refused is None and a.result is not None
        gerr = relative_gain_error(np.asarray(a.result.K), K_star) if learned else None
        res[name] = (a.refused is None, gerr, a.refused, rms)
    return res


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--noise", type=float, nargs="+", default=[1.0, 0.5], help="m")
    parser.add_argument("--draws", type=int, nargs="+", default=[1, 2, 3], help="seeds")
    parser.add_argument("--lags", type=int, nargs="*", default=[6, 30, 60], help="samples")
    parser.add_argument(
        "--accels",
        type=float,
        nargs="*",
        default=[3e-5, 1e-5, 3e-6],
        help="retuned filter acceleration noise, m/s^2 (the flight's is 1e-4)",
    )
    args = parser.parse_args()
    for noise in args.noise:
        for seed in args.draws:
            t0 = time.perf_counter()
            r = draw(noise, seed, args.lags, args.accels)
            print(
                f"## noise {noise} m, draw {seed} ({time.perf_counter() - t0:.0f} s); "
                f"flight attempt: {r['flight']}",
                flush=True,
            )
            for name in [k for k in r if k not in ("noise", "seed", "flight")]:
                ok, gerr, why, rms = r[name]
                g = "-" if gerr is None else f"{gerr:.3g}"
                print(
                    f"| {noise} | {seed} | {name} | {'yes' if ok else 'no'} | {g} | "
                    f"{rms[0]:.3f} / {rms[1]:.3f} m, {1e3 * rms[2]:.3f} / {1e3 * rms[3]:.3f} mm/s "
                    f"| {(why or '')[:40]} |",
                    flush=True,
                )


if __name__ == "__main__":
    main()
