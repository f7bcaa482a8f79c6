"""RegulationProblem validation and its standing-assumption checks."""

from __future__ import annotations

import numpy as np
import pytest

from ddvi_core import models
from ddvi_core.problem import ProblemError, RegulationProblem, numerical_rank

DI_A = np.array([[0.0, 1.0], [0.0, 0.0]])
DI_B = np.array([[0.0], [1.0]])


def _check(report, name_part: str):
    matches = [c for c in report.checks if name_part in c.name]
    assert len(matches) == 1, [c.name for c in report.checks]
    return matches[0]


# ---- validation -----------------------------------------------------------------------------
def test_wrong_shape_names_matrix_and_shapes() -> None:
    with pytest.raises(ProblemError) as exc:
        RegulationProblem(A=DI_A, B=np.zeros((3, 1)), Q=np.eye(2), R=np.eye(1))
    msg = str(exc.value)
    assert msg.startswith("B")
    assert "2x?" in msg and "3x1" in msg

    with pytest.raises(ProblemError, match=r"Q: expected shape 2x2, got 3x3"):
        RegulationProblem(A=DI_A, B=DI_B, Q=np.eye(3), R=np.eye(1))
    with pytest.raises(ProblemError, match=r"A: must be square, got 2x3"):
        RegulationProblem(A=np.zeros((2, 3)), B=DI_B, Q=np.eye(2), R=np.eye(1))


def test_non_symmetric_Q_names_entries() -> None:
    Q = np.array([[1.0, 0.5], [0.2, 1.0]])
    with pytest.raises(ProblemError) as exc:
        RegulationProblem(A=DI_A, B=DI_B, Q=Q, R=np.eye(1))
    msg = str(exc.value)
    assert "symmetric" in msg
    assert ("Q[0,1]" in msg and "Q[1,0]" in msg) and "0.5" in msg and "0.2" in msg


@pytest.mark.parametrize("R", [[[-1.0]], [[0.0]]])
def test_R_not_positive_definite(R) -> None:
    with pytest.raises(ProblemError, match="R: must be positive definite"):
        RegulationProblem(A=DI_A, B=DI_B, Q=np.eye(2), R=R)


def test_indefinite_R_two_inputs() -> None:
    with pytest.raises(ProblemError, match="R"):
        RegulationProblem(A=DI_A, B=np.eye(2), Q=np.eye(2), R=[[1.0, 2.0], [2.0, 1.0]])


def test_indefinite_Q_rejected() -> None:
    with pytest.raises(ProblemError, match="Q: must be positive semidefinite"):
        RegulationProblem(A=DI_A, B=DI_B, Q=np.diag([1.0, -1.0]), R=np.eye(1))


def test_nan_rejected() -> None:
    A = DI_A.copy()
    A[0, 0] = np.nan
    with pytest.raises(ProblemError, match=r"A: .*non-finite"):
        RegulationProblem(A=A, B=DI_B, Q=np.eye(2), R=np.eye(1))
    with pytest.raises(ProblemError, match=r"Q: .*non-finite"):
        RegulationProblem(A=DI_A, B=DI_B, Q=[[np.inf, 0], [0, 1]], R=np.eye(1))


def test_incomplete_exosystem() -> None:
    with pytest.raises(ProblemError) as exc:
        RegulationProblem(
            A=DI_A,
            B=DI_B,
            Q=np.eye(2),
            R=np.eye(1),
            C=[[1.0, 0.0]],
            E=np.zeros((1, 1)),
            D=np.zeros((2, 1)),
        )
    msg = str(exc.value)
    assert "incomplete" in msg and "F" in msg.split("but")[1]
    with pytest.raises(ProblemError, match="C: required"):
        RegulationProblem(
            A=DI_A,
            B=DI_B,
            Q=np.eye(2),
            R=np.eye(1),
            E=np.zeros((1, 1)),
            D=np.zeros((2, 1)),
            F=np.zeros((1, 1)),
        )


def test_sizes_and_numeric_coercion() -> None:
    P = RegulationProblem(
        A=DI_A.tolist(),
        B=DI_B.tolist(),
        Q=np.eye(2),
        R=2.0,
        C=[[1.0, 0.0]],
        E=[[0.0]],
        D=[[0.0], [0.0]],
        F=[[-1.0]],
    )
    assert (P.n, P.m, P.p, P.q) == (2, 1, 1, 1)
    assert P.has_exosystem
    assert P.R.shape == (1, 1) and P.C.shape == (1, 2)


def test_numerical_rank() -> None:
    assert numerical_rank(np.zeros((0, 3))) == 0
    assert numerical_rank(np.zeros((3, 3))) == 0
    assert numerical_rank(np.diag([1.0, 1e-3, 1e-12])) == 2


# ---- assumptions ----------------------------------------------------------------------------
def test_double_integrator_all_hold() -> None:
    P = RegulationProblem(
        A=DI_A,
        B=DI_B,
        Q=np.eye(2),
        R=np.eye(1),
        C=[[1.0, 0.0]],
        E=[[0.0, -1.0], [1.0, 0.0]],
        D=np.zeros((2, 2)),
        F=[[-1.0, 0.0]],
    )
    rep = P.check_assumptions()
    assert rep.ok and rep.failures == ()
    assert len(rep.checks) == 3
    assert rep.as_dict()["ok"] is True


def test_uncontrollable_unstable_names_eigenvalue() -> None:
    A = np.diag([1.0, -1.0])
    B = np.array([[0.0], [1.0]])
    rep = RegulationProblem(A=A, B=B, Q=np.eye(2), R=np.eye(1)).check_assumptions()
    assert not rep.ok
    stab = _check(rep, "stabilisable")
    assert not stab.holds
    assert "eigenvalue 1 of A" in stab.detail
    assert _check(rep, "detectable").holds


def test_Q_missing_unstable_mode_not_detectable() -> None:
    A = np.diag([1.0, -1.0])
    B = np.array([[1.0], [1.0]])
    rep = RegulationProblem(A=A, B=B, Q=np.diag([0.0, 1.0]), R=np.eye(1)).check_assumptions()
    assert _check(rep, "stabilisable").holds
    det = _check(rep, "detectable")
    assert not det.holds and "eigenvalue 1 of A" in det.detail
    assert [c.name for c in rep.failures] == [det.name]


def test_transmission_zero_at_exosystem_eigenvalue() -> None:
    # G(s) = (s^2 + 4) / s^3: zeros at +-2j, exosystem at frequency 2
    A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]])
    B = np.array([[0.0], [0.0], [1.0]])
    C = np.array([[4.0, 0.0, 1.0]])
    E = np.array([[0.0, -2.0], [2.0, 0.0]])
    P = RegulationProblem(
        A=A, B=B, Q=np.eye(3), R=np.eye(1), C=C, E=E, D=np.zeros((3, 2)), F=[[1.0, 0.0]]
    )
    rep = P.check_assumptions()
    reg = _check(rep, "regulator")
    assert not reg.holds
    assert "2j" in reg.detail and "needed n + p = 4" in reg.detail
    assert _check(rep, "stabilisable").holds and _check(rep, "detectable").holds
    # the same plant tracking frequency 1 is fine
    E1 = np.array([[0.0, -1.0], [1.0, 0.0]])
    P1 = RegulationProblem(
        A=A, B=B, Q=np.eye(3), R=np.eye(1), C=C, E=E1, D=np.zeros((3, 2)), F=[[1.0, 0.0]]
    )
    assert P1.check_assumptions().ok


def test_paper_printed_problem_fails_as_documented() -> None:
    P = models.paper_printed_problem()
    rep = P.check_assumptions()
    stab = _check(rep, "stabilisable")
    assert not stab.holds
    # the z mode: s^2 + (damp/2) s - nbar^2 = 0 has a root near +nbar = 0.00108
    eig = np.linalg.eigvals(P.A[np.ix_([2, 5], [2, 5])])
    z_unstable = float(np.max(eig.real))
    assert z_unstable == pytest.approx(0.00108, rel=1e-6)
    assert f"eigenvalue {z_unstable:.6g} of A" in stab.detail
    reg = _check(rep, "regulator")
    assert not reg.holds
    assert "needed n + p = 9" in reg.detail and "m = 3" not in reg.detail  # m == p here
    # rank B = 1 bounds the Rosenbrock rank by n + 1 = 7 at every eigenvalue of E
    for w in (0.1, 0.2, 0.3, 0.4):
        assert f"{w:.6g}j" in reg.detail


@pytest.mark.parametrize("factory", [models.rendezvous_problem, models.thrust_rendezvous_problem])
def test_mission_problems_pass_every_assumption(factory) -> None:
    rep = factory().check_assumptions()
    assert rep.ok, rep.as_dict()
    assert len(rep.checks) == 3
