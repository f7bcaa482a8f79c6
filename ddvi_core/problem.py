"""The optimal output regulation problem and its standing assumptions.

    v' = E v                 exosystem            v in R^q
    x' = A x + B u + D v     plant                x in R^n, u in R^m
    e  = C x + F v           tracking error       e in R^p
    cost  integral of (x^T Q x + u^T R u) dt on the error system (Problem 2)

Without an exosystem (E, D, F absent) it is plain optimal stabilisation.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike, NDArray

__all__ = [
    "AssumptionCheck",
    "AssumptionReport",
    "ProblemError",
    "RegulationProblem",
    "numerical_rank",
]


class ProblemError(ValueError):
    """A regulation problem whose data are malformed (shape, symmetry, definiteness, NaN)."""


def numerical_rank(M: NDArray[np.float64], rtol: float = 1e-9) -> int:
    """Rank of M counting singular values above ``rtol`` times the largest one."""
    if M.size == 0:
        return 0
    s = np.linalg.svd(M, compute_uv=False)
    if s[0] == 0.0:
        return 0
    return int(np.sum(s > rtol * s[0]))


def _matrix(name: str, value: ArrayLike, shape: tuple[int | None, int | None]) -> NDArray:
    try:
        M = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ProblemError(f"{name}: not a numeric matrix ({exc})") from None
    if M.ndim == 1 and shape[0] == 1:  # a single row given as a flat list
        M = M.reshape(1, -1)
    if M.ndim == 0 and shape == (1, 1):
        M = M.reshape(1, 1)
    if M.ndim != 2:
        raise ProblemError(f"{name}: expected a matrix (list of rows), got {M.ndim}-D data")
    for axis, want in enumerate(shape):
        if want is not None and M.shape[axis] != want:
            expected = "x".join("?" if s is None else str(s) for s in shape)
            raise ProblemError(f"{name}: expected shape {expected}, got {M.shape[0]}x{M.shape[1]}")
    if not np.all(np.isfinite(M)):
        raise ProblemError(f"{name}: contains a non-finite entry (NaN or inf)")
    return M


def _check_symmetric(name: str, M: NDArray) -> None:
    scale = max(1.0, float(np.max(np.abs(M))))
    if not np.allclose(M, M.T, rtol=0.0, atol=1e-12 * scale):
        i, j = np.unravel_index(np.argmax(np.abs(M - M.T)), M.shape)
        raise ProblemError(
            f"{name}: must be symmetric, but {name}[{i},{j}] = {M[i, j]:g} "
            f"and {name}[{j},{i}] = {M[j, i]:g}"
        )


@dataclass(frozen=True)
class AssumptionCheck:
    """One standing assumption: its name, whether it holds, and a sentence saying why."""

    name: str
    holds: bool
    detail: str


@dataclass(frozen=True)
class AssumptionReport:
    """Every assumption the paper's Problems 1 and 2 rely on, checked on one problem."""

    checks: tuple[AssumptionCheck, ...]

    @property
    def ok(self) -> bool:
        return all(c.holds for c in self.checks)

    @property
    def failures(self) -> tuple[AssumptionCheck, ...]:
        return tuple(c for c in self.checks if not c.holds)

    def as_dict(self) -> dict:
        return {
            "ok": self.ok,
            "checks": [{"name": c.name, "holds": c.holds, "detail": c.detail} for c in self.checks],
        }


def _fmt_eig(lam: complex) -> str:
    if abs(lam.imag) <= 1e-12 * max(1.0, abs(lam)):
        return f"{lam.real:.6g}"
    return f"{lam.real:.6g}{lam.imag:+.6g}j"


@dataclass(frozen=True)
class RegulationProblem:
    """Matrices of an optimal output regulation problem, validated on construction.

    Shapes: A (n, n), B (n, m), Q (n, n) symmetric PSD, R (m, m) symmetric PD; with an
    exosystem also E (q, q), D (n, q), C (p, n), F (p, q).  ``C`` alone (no exosystem) is
    allowed and only used for reporting.
    """

    A: NDArray[np.float64]
    B: NDArray[np.float64]
    Q: NDArray[np.float64]
    R: NDArray[np.float64]
    C: NDArray[np.float64] | None = None
    D: NDArray[np.float64] | None = None
    E: NDArray[np.float64] | None = None
    F: NDArray[np.float64] | None = None
    name: str = field(default="problem", compare=False)

    def __post_init__(self) -> None:
        A = _matrix("A", self.A, (None, None))
        n = A.shape[0]
        if A.shape != (n, n):
            raise ProblemError(f"A: must be square, got {A.shape[0]}x{A.shape[1]}")
        B = _matrix("B", self.B, (n, None))
        m = B.shape[1]
        Q = _matrix("Q", self.Q, (n, n))
        R = _matrix("R", self.R, (m, m))
        _check_symmetric("Q", Q)
        _check_symmetric("R", R)
        if np.min(np.linalg.eigvalsh(Q)) < -1e-12 * max(1.0, np.max(np.abs(Q))):
            raise ProblemError("Q: must be positive semidefinite (it has a negative eigenvalue)")
        if np.min(np.linalg.eigvalsh(R)) <= 0.0:
            raise ProblemError("R: must be positive definite (it has an eigenvalue <= 0)")
        object.__setattr__(self, "A", A)
        object.__setattr__(self, "B", B)
        object.__setattr__(self, "Q", Q)
        object.__setattr__(self, "R", R)

        exo = {k: getattr(self, k) for k in ("D", "E", "F")}
        given = [k for k, val in exo.items() if val is not None]
        if given and len(given) < 3:
            missing = sorted(set(exo) - set(given))
            raise ProblemError(
                f"exosystem is incomplete: {', '.join(given)} given but {', '.join(missing)} "
                "missing (give E, D and F together, or none of them)"
            )
        if given and self.C is None:
            raise ProblemError("C: required when an exosystem (E, D, F) is given")
        if self.C is not None:
            C = _matrix("C", self.C, (None, n))
            object.__setattr__(self, "C", C)
        if given:
            E = _matrix("E", self.E, (None, None))
            q = E.shape[0]
            if E.shape != (q, q):
                raise ProblemError(f"E: must be square, got {E.shape[0]}x{E.shape[1]}")
            object.__setattr__(self, "E", E)
            object.__setattr__(self, "D", _matrix("D", self.D, (n, q)))
            object.__setattr__(self, "F", _matrix("F", self.F, (self.C.shape[0], q)))

    # ---- sizes -------------------------------------------------------------------------
    @property
    def n(self) -> int:
        return self.A.shape[0]

    @property
    def m(self) -> int:
        return self.B.shape[1]

    @property
    def p(self) -> int:
        return 0 if self.C is None else self.C.shape[0]

    @property
    def q(self) -> int:
        return 0 if self.E is None else self.E.shape[0]

    @property
    def has_exosystem(self) -> bool:
        return self.E is not None

    # ---- assumptions -------------------------------------------------------------------
    def check_assumptions(self, rtol: float = 1e-9) -> AssumptionReport:
        """Stabilisability of (A, B), detectability of (A, sqrt(Q)), and, with an exosystem,
        the regulator-equation rank condition rank[[A - lam I, B], [C, 0]] = n + p for every
        eigenvalue lam of E.  Ranks are numerical (singular values above rtol * largest) on a
        balanced copy of the matrices, so that physical units do not decide the verdict.
        """
        n = self.n
        Ab, Bb, Cb, sqrtQb, rate = self._balanced()
        unstable = [lam for lam in np.linalg.eigvals(self.A) if lam.real >= -1e-12 * rate]
        checks: list[AssumptionCheck] = []

        bad = []
        for lam in _unique(unstable):
            r = numerical_rank(np.hstack([Ab - (lam / rate) * np.eye(n), _unit_cols(Bb)]), rtol)
            if r < n:
                bad.append(
                    f"eigenvalue {_fmt_eig(lam)} of A is not controllable from u: "
                    f"rank[A - lam I, B] = {r}, needed {n}"
                )
        checks.append(
            AssumptionCheck(
                "stabilisable (A, B)",
                not bad,
                "; ".join(bad) or "every eigenvalue of A with Re >= 0 is controllable from u",
            )
        )

        bad = []
        for lam in _unique(unstable):
            r = numerical_rank(np.vstack([Ab - (lam / rate) * np.eye(n), _unit_rows(sqrtQb)]), rtol)
            if r < n:
                bad.append(
                    f"eigenvalue {_fmt_eig(lam)} of A is not seen by the cost: "
                    f"rank[A - lam I; sqrt(Q)] = {r}, needed {n}"
                )
        checks.append(
            AssumptionCheck(
                "detectable (A, sqrt(Q))",
                not bad,
                "; ".join(bad) or "every eigenvalue of A with Re >= 0 is weighted by Q",
            )
        )

        if self.has_exosystem:
            p = self.p
            bad = []
            for lam in _unique(list(np.linalg.eigvals(self.E))):
                M = np.block(
                    [
                        [Ab - (lam / rate) * np.eye(n), _unit_cols(Bb)],
                        [_unit_rows(Cb), np.zeros((p, self.m))],
                    ]
                )
                r = numerical_rank(M, rtol)
                if r < n + p:
                    bad.append(
                        f"eigenvalue {_fmt_eig(lam)} of E: rank[[A - lam I, B], [C, 0]] = {r}, "
                        f"needed n + p = {n + p}"
                        + (
                            f" (with m = {self.m} inputs at most {n + self.m} is possible)"
                            if self.m < p
                            else ""
                        )
                    )
            rank_B = numerical_rank(_unit_cols(self.B), rtol)
            if bad and rank_B < p:
                bad.insert(
                    0,
                    f"rank B = {rank_B} < p = {p}: {rank_B} effective input(s) cannot "
                    f"regulate {p} outputs, so rank n + p is out of reach",
                )
            checks.append(
                AssumptionCheck(
                    "regulator equations solvable",
                    not bad,
                    "; ".join(bad)
                    or f"rank[[A - lam I, B], [C, 0]] = n + p = {n + p} for every eigenvalue of E",
                )
            )
        return AssumptionReport(tuple(checks))

    def _balanced(self) -> tuple[NDArray, NDArray, NDArray, NDArray, float]:
        """A, B, C, sqrt(Q) after a diagonal similarity that balances A (scipy's
        matrix_balance) and with time in units of A's fastest rate.  Ranks of the PBH and
        Rosenbrock matrices are invariant under both, but their numerical verdicts are not."""
        _, (scale, _) = scipy.linalg.matrix_balance(self.A, permute=False, separate=True)
        A = self.A * scale[None, :] / scale[:, None]
        rate = float(np.max(np.abs(np.linalg.eigvals(A))))
        if rate == 0.0:
            rate = float(np.max(np.abs(A))) or 1.0
        w, V = np.linalg.eigh(self.Q)
        sqrtQ = (V * np.sqrt(np.clip(w, 0.0, None))) @ V.T
        C = self.C if self.C is not None else np.zeros((0, self.n))
        return A / rate, self.B / scale[:, None] / rate, C * scale, sqrtQ * scale, rate


def _unit_cols(M: NDArray) -> NDArray:
    """Columns scaled to unit norm (zero columns left zero): rank-preserving balancing."""
    norms = np.linalg.norm(M, axis=0)
    return M / np.where(norms > 0, norms, 1.0)


def _unit_rows(M: NDArray) -> NDArray:
    norms = np.linalg.norm(M, axis=1, keepdims=True)
    return M / np.where(norms > 0, norms, 1.0)


def _unique(values: list[complex], tol: float = 1e-9) -> list[complex]:
    out: list[complex] = []
    for v in values:
        if all(abs(v - w) > tol * max(1.0, abs(w)) for w in out):
            out.append(complex(v))
    return out
