"""Each piece of control algebra has one home (issue 33, "control algebra once"): a grep over the
source tree fails when a second Riccati solver, ``solve_discrete_are`` call, one-step residual,
double integrator, upper-triangle mirror or Pinocchio import appears in ``hydroarm.control``
outside its home; and the homes compute what they say (closed forms, SciPy)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

import hydroarm
from hydroarm.control import linear
from hydroarm.control.learned_water import PhysicsInformedModel
from hydroarm.control.linear import joint_lqr
from hydroarm.control.observers import DisturbanceObserver, ObservedController, ObserverConfig
from hydroarm.control.smc import SlidingModeController
from hydroarm.model.dynamics import fixed_order
from hydroarm.model.dynamics.nominal import NominalModel

SOURCE = Path(hydroarm.__file__).parent
CONTROL = SOURCE / "control"

RESIDUAL_EXCEPTIONS = {
    "control/uvms_control.py": "the vehicle's body-wrench residual (its own rigid body, no arm dynamics)",
}
"""Functions in control/ named ``*residual*`` that are not the arm's one-step residual, and why."""


def _code_lines(path: Path) -> list[tuple[int, str]]:
    """The module's lines without its docstrings and comments (code only), numbered from 1."""
    text = path.read_text()
    docstrings = set()
    for node in ast.walk(ast.parse(text)):
        body = getattr(node, "body", None)
        if isinstance(body, list) and body and isinstance(body[0], ast.Expr):
            value = body[0].value
            if isinstance(value, ast.Constant) and isinstance(value.value, str):
                docstrings.update(range(value.lineno, value.end_lineno + 1))
    return [
        (number, line.split("#", 1)[0]) for number, line in enumerate(text.splitlines(), 1) if number not in docstrings
    ]


def _hits(pattern: str, root: Path | None = None) -> set[str]:
    """``module:line`` of every code line under ``root`` (default: control/) matching the regex ``pattern``."""
    found = set()
    for path in sorted((root or CONTROL).rglob("*.py")):
        for number, line in _code_lines(path):
            if re.search(pattern, line):
                found.add(f"{path.relative_to(SOURCE).as_posix()}:{number}")
    return found


def _modules(hits: set[str]) -> set[str]:
    return {hit.rsplit(":", 1)[0] for hit in hits}


def test_no_controller_imports_pinocchio():
    """The dry-dynamics facade (model.nominal) is the controllers' only way to Pinocchio."""
    assert _hits(r"^\s*(import pinocchio|from pinocchio)") == set()
    assert _hits(r"\bpin\.") == set()


def test_one_riccati_solver_home():
    """``solve_discrete_are``, the doubling and the filter's fixed-point iteration live in
    control/linear.py only; nothing else in src calls scipy's DARE or defines a Riccati solver."""
    assert _modules(_hits(r"solve_discrete_are|solve_continuous_are", SOURCE)) == {"control/linear.py"}
    assert _modules(_hits(r"def \w*(riccati|doubling|dare)\w*\(", SOURCE)) == {"control/linear.py"}


def test_one_double_integrator():
    """``A = [[1, T], [0, 1]]`` and ``B = [T^2/2, T]`` are built in control/linear.py only."""
    assert _modules(_hits(r"\[\[1\.0, \w+\], \[0\.0, 1\.0\]\]", SOURCE)) == {"control/linear.py"}
    assert _modules(_hits(r"\[0\.5 \* (\w+) \* \1, \1\]", SOURCE)) == {"control/linear.py"}


def test_one_upper_triangle_mirror():
    """The mirror of an upper triangle (once ``np.triu(M) + np.triu(M, 1).T``, eight times) is
    ``fixed_order.symmetrize`` alone: no ``np.triu`` left in src, and the mirror's loop
    (``out[j, i] = value``) in model/dynamics/fixed_order.py only."""
    assert _modules(_hits(r"np\.triu\(", SOURCE)) == set()
    assert _modules(_hits(r"out\[j, i\] = value", SOURCE)) == {"model/dynamics/fixed_order.py"}


def test_one_residual():
    """Every ``*residual*`` function of control/ delegates to the dry model's
    (``NominalModel.residual`` / ``tde_residual``) unless listed with its reason; no module of
    control/ multiplies a mass matrix into a velocity change itself."""
    for path in sorted(CONTROL.rglob("*.py")):
        module = path.relative_to(SOURCE).as_posix()
        if module in RESIDUAL_EXCEPTIONS:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef) and "residual" in node.name:
                if f"{module}:{node.name}" in RESIDUAL_EXCEPTIONS:
                    continue
                calls = {c.func.attr for c in ast.walk(node) if isinstance(c, ast.Call) and hasattr(c.func, "attr")}
                assert calls & {"residual", "tde_residual"}, f"{module}:{node.name} computes its own residual"
    assert _hits(r"(mass|M)\w* @ \(\w+\[n:\] - ") == set()
    assert _hits(r"matvec\(\w*mass\w*, \w+\[n:\] - ") == set()


@pytest.fixture(scope="module")
def nominal(paper_arm):
    return NominalModel(paper_arm, inner_step=None)


def _transitions(n: int, count: int = 5):
    rng = np.random.default_rng(3)
    return [
        (rng.standard_normal(2 * n), 10.0 * rng.standard_normal(n), rng.standard_normal(2 * n)) for _ in range(count)
    ]


def test_the_residuals_vanish_on_their_own_predictions(nominal):
    """Closed forms: the RK4 residual is 0 on the RK4 prediction; the TDE residual is 0 (to
    rounding) on the explicit Euler step of the dry model, and ``M (v_next - v) / T + h - u``
    by hand otherwise."""
    n, period = nominal.n, 0.01
    for y, u, y_next in _transitions(n):
        w, predicted = nominal.residual(y, u, y_next, period)
        assert np.array_equal(nominal.residual(y, u, predicted, period)[0], np.zeros(n))
        euler = nominal.euler_step(y, u, period)
        scale = np.abs(nominal.nonlinear_effects(y[:n], y[n:]) - u).max()
        assert np.abs(nominal.tde_residual(y, u, euler, period)).max() <= 1e-12 * max(scale, 1.0)
        mass = nominal.mass_matrix(y[:n])
        by_hand = mass @ (y_next[n:] - y[n:]) / period + nominal.nonlinear_effects(y[:n], y[n:]) - u
        np.testing.assert_allclose(nominal.tde_residual(y, u, y_next, period), by_hand, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(w, mass @ (y_next[n:] - predicted[n:]) / period, rtol=1e-12, atol=1e-9)


def test_the_observer_and_the_water_model_take_the_one_residual(paper_arm, nominal):
    """Both learners' residual is NominalModel.tde_residual, bit for bit (the observers with
    NumPy's product, the water model with the fixed-order one, as they always were)."""
    period = 0.01
    observer = DisturbanceObserver(paper_arm, period, ObserverConfig(kind="tde"))
    observed = ObservedController(SlidingModeController(paper_arm, control_period=period), observer, paper_arm)
    water = PhysicsInformedModel(paper_arm)
    for y, u, y_next in _transitions(nominal.n):
        observed.observe(0.0, y, u, y_next)  # the TDE's estimate is the residual it was given
        assert np.array_equal(observer.mean(y), nominal.tde_residual(y, u, y_next, period, "blas"))
        assert np.array_equal(water.residual(y, u, y_next, period), nominal.tde_residual(y, u, y_next, period))
    with pytest.raises(ValueError, match="product"):
        nominal.missed_force(np.zeros(nominal.n), np.zeros(nominal.n), period, "lapack")


def test_one_torque_map_over_the_box():
    """The ID-MPC's torque held within its box (the limits, or the drives' rate box within them)
    is one function, ``idmpc_limits.held_torque``, over ``torque_box()``, with one allocation
    (``box_allocate`` about the box's centre on ``allocate``): no second ``*limited_torque``, no
    box map of its own, and only ``limited_torque`` calls the map (issue 32's review debt: the
    rate path was a near-copy of the symmetric one)."""
    assert _hits(r"def \w*limited_torque\w*\(") == {_single(r"def limited_torque\(", "control/idmpc.py")}
    assert _modules(_hits(r"def (held_torque|box_allocate|allocate)\(mass|def held_torque\(")) == {
        "control/idmpc_limits.py"
    }
    assert _modules(_hits(r"\bheld_torque\(")) == {"control/idmpc_limits.py", "control/idmpc.py"}
    assert _modules(_hits(r"SATURATION_TOLERANCE =|1e-9 \* np\.maximum|\(1\.0 - 1e-9\)")) == {"control/idmpc_limits.py"}


def _single(pattern: str, module: str) -> str:
    """The one ``module:line`` in control/ matching ``pattern`` (asserted to be in ``module``)."""
    (hit,) = _hits(pattern)
    assert hit.startswith(module + ":")
    return hit


def test_symmetrize_mirrors_the_upper_triangle():
    upper = np.triu(np.arange(16.0).reshape(4, 4)) + np.tril(np.full((4, 4), np.nan), -1)
    full = fixed_order.symmetrize(upper)
    assert np.array_equal(full, full.T)
    assert np.array_equal(np.triu(full), np.triu(upper))


def test_symmetrize_equals_the_triu_expression_it_replaced_bit_for_bit():
    """The compiled mirror gives what ``np.triu(M) + np.triu(M, 1).T`` gave, signed zeros
    included (-0.0 + 0.0 = +0.0), for C- and Fortran-ordered input (Pinocchio's M)."""
    rng = np.random.default_rng(3)
    for n in (1, 6, 7):
        upper = rng.standard_normal((n, n))
        upper[0, n - 1] = -0.0
        upper[n // 2, n // 2] = -0.0
        for matrix in (upper, np.asfortranarray(upper)):
            expected = np.triu(matrix) + np.triu(matrix, 1).T
            full = fixed_order.symmetrize(matrix)
            assert np.array_equal(full, expected)
            assert np.array_equal(np.signbit(full), np.signbit(expected))


def test_both_dare_solvers_solve_the_dare_and_say_which_ran():
    """SciPy's Schur solution and the doubling agree, and P satisfies the DARE (residual form)."""
    rng = np.random.default_rng(1)
    A = np.eye(6) + 0.05 * rng.standard_normal((6, 6))
    B = rng.standard_normal((6, 3))
    Q, R = np.eye(6), 0.1 * np.eye(3)
    P_doubling, iterations, used = linear.solve_dare(A, B, Q, R, "doubling")
    P_scipy, none, used_scipy = linear.solve_dare(A, B, Q, R, "scipy")
    assert (used, used_scipy, none) == ("doubling", "scipy", 0) and iterations > 0
    np.testing.assert_allclose(P_doubling, P_scipy, rtol=1e-9)
    gain = linear.lqr_gain(A, B, R, P_scipy)
    np.testing.assert_allclose(A.T @ P_scipy @ A - A.T @ P_scipy @ B @ gain + Q, P_scipy, rtol=1e-9, atol=1e-9)
    assert linear.solve_dare(A, B, Q, R, "doubling", max_iterations=1)[2] == "scipy"
    with pytest.raises(ValueError, match="method"):
        linear.solve_dare(A, B, Q, R, "newton")


def test_the_idmpc_joint_lqr_is_the_fixed_order_dare_on_the_double_integrator():
    """``joint_lqr``'s P is ``linear.joint_dare``'s (its one Riccati solver since 2026-12-05, no
    LAPACK), within 1e-12 of scipy's ``solve_discrete_are``."""
    T = 0.01
    A, b = linear.double_integrator(T)
    P = scipy.linalg.solve_discrete_are(A, b[:, None], np.diag([300.0, 0.01]), np.array([[1e-5]]))
    p00, p01, p11 = linear.joint_dare(T, 300.0, 0.01, 1e-5)[:3]
    got = joint_lqr(T, 300.0, 0.01, 1e-5)[0]
    assert np.array_equal(got, np.array([[p00, p01], [p01, p11]]))
    assert np.max(np.abs(got - P)) <= 1e-12 * np.max(np.abs(P))


def test_the_reference_defects_vanish_for_a_constant_acceleration():
    """c_k = x_r,k+1 - A x_r,k - B a_r,k is zero on a reference of constant acceleration, and the
    batched call (leading axes) is the single one's, bit for bit."""
    T, a = 0.01, np.array([0.3, -2.0])
    t = np.arange(6)[:, None] * T
    q, v = 0.1 + 0.5 * t + 0.5 * a * t**2, 0.5 + a * t
    c = linear.reference_defects(q, v, np.broadcast_to(a, q.shape), T)
    assert c.shape == (5, 2, 2)
    np.testing.assert_allclose(c, 0.0, atol=1e-15)
    stacked = linear.reference_defects(np.stack([q, 2 * q]), np.stack([v, 2 * v]), np.stack([v, v]), T)
    assert np.array_equal(stacked[0], linear.reference_defects(q, v, v, T))
