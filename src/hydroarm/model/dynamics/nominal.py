"""The nominal (dry) model: what every controller knows of the arm ("tuned once on land").

One object serves every controller: the dry rigid body ``M(q) q'' + C(q, v) v + G(q) = tau``
of an :class:`~hydroarm.model.arm.description.Arm`, no water, no current. It owns its Pinocchio
workspace (one per controller), and it is the controllers' only way to the rigid-body
algorithms: no module of :mod:`hydroarm.control` imports Pinocchio (tests/test_single_home.py).
It offers

* the dry dynamics at one instant (CRBA, RNEA, ABA and their analytical derivatives);
* :meth:`NominalModel.predict`: the state after a period under a held torque (classic RK4,
  ``ceil(dt / inner_step)`` steps, or one step of dt when ``inner_step`` is None), and
  :meth:`NominalModel.step` with the plant's interface;
* the one-step residual, the generalised force (N m) the dry model missed over a measured step
  ``y -> y_next`` under the torque u, written once (:meth:`NominalModel.missed_force`,
  ``M(q) dv / T``) in its two forms: :meth:`NominalModel.residual`, ``M(q) (v_next -
  v_nominal) / T`` against the RK4 prediction (what the GPs learn), and
  :meth:`NominalModel.tde_residual`, ``M(q) (v_next - v) / T + h(q, v) - u`` (the time-delay
  estimate: the disturbance observers' and the physics-informed water model's target);
* :meth:`NominalModel.linearise`: the discrete prediction model of an MPC, ``(A, B, x_next)``
  of the explicit Euler step ``x + T [v, q'']`` or of the second-order Taylor step
  ``q+ = q + T v + T^2/2 q''``, ``v+ = v + T q''`` (exact for a constant acceleration over the
  step), with Pinocchio's analytical ABA derivatives.

Units: SI (rad, rad/s, rad/s^2, N m, s). State x = [q, v] (2n,).
"""

from __future__ import annotations

import numba
import numpy as np
import pinocchio as pin

from hydroarm.config import ConfigError
from hydroarm.model.arm.description import Arm
from hydroarm.model.dynamics import fixed_order
from hydroarm.model.dynamics.integrator import StepInfo, inner_steps, rk4_second_order_stage, rk4_step

DISCRETISATIONS = ("euler", "taylor2")

PRODUCTS = ("fixed", "blas")
"""The matrix-vector products of :meth:`NominalModel.missed_force`."""


class NominalModel:
    """The dry model of ``arm`` with its own workspace (see the module docstring).

    ``inner_step`` (s): the RK4 step of :meth:`predict` and :meth:`step`; None = one
    RK4 step over the whole period.
    """

    def __init__(self, arm: Arm, inner_step: float | None = 1e-3):
        self.arm = arm
        self.n = arm.n_joints
        self.inner_step = inner_step
        self.data = arm.create_data()
        self._stages = np.empty((4, 2 * self.n))
        self._zero = np.zeros(self.n)

    # --- the dry dynamics at one instant ----------------------------------------------
    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """M(q) (kg m^2), shape (n, n), symmetric (CRBA)."""
        return fixed_order.symmetrize(pin.crba(self.arm.model, self.data, q))

    def mass_matrix_upper(self, q: np.ndarray) -> np.ndarray:
        """M(q) (n, n) as CRBA leaves it, only its upper triangle filled: a view into the
        workspace, valid until its next CRBA (for compiled callers that read the upper triangle)."""
        return pin.crba(self.arm.model, self.data, q)

    def nonlinear_effects(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """C(q, v) v + G(q) (N m), shape (n,)."""
        return pin.nonLinearEffects(self.arm.model, self.data, q, v).copy()

    def inverse_dynamics(self, q: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        """tau = M a + C v + G (N m), shape (n,) (RNEA)."""
        return pin.rnea(self.arm.model, self.data, q, v, a).copy()

    def forward_dynamics(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """q'' = M^-1 (tau - C v - G) (rad/s^2), shape (n,) (ABA)."""
        return pin.aba(self.arm.model, self.data, q, v, tau).copy()

    def forward_dynamics_derivatives(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray):
        """``(q'', dq''/dq, dq''/dv, M^-1)``: ABA and its analytical derivatives, (n,) and (n, n) x 3."""
        return self.arm.forward_dynamics_derivatives(q, v, tau, data=self.data)

    def inverse_dynamics_derivatives(self, q: np.ndarray, v: np.ndarray, a: np.ndarray):
        """``(tau (n,), dtau/dq (n, n), dtau/dv (n, n), M (n, n))``: RNEA and its analytical
        derivatives as Pinocchio's ``computeRNEADerivatives`` gives them (views into the workspace,
        valid until its next call; copy what is kept)."""
        d_q, d_v, mass = pin.computeRNEADerivatives(self.arm.model, self.data, q, v, a)
        return self.data.tau, d_q, d_v, mass

    # --- prediction ------------------------------------------------------------------
    def predict(self, x: np.ndarray, tau: np.ndarray, dt: float) -> np.ndarray:
        """The dry state (2n,) after ``dt`` (s) from ``x`` (2n,) under constant ``tau`` (n,): RK4.

        The RK4 arithmetic is compiled (:func:`~hydroarm.model.dynamics.integrator.rk4_second_order_stage`);
        the same numbers as :meth:`predict_numpy`, bit for bit.
        """
        n, model, data = self.n, self.arm.model, self.data
        steps, h = inner_steps(dt, self.inner_step)
        state = np.array(x, dtype=float)
        stage_state = state.copy()
        q, v = stage_state[:n], stage_state[n:]
        tau = np.ascontiguousarray(tau, dtype=float)
        for _ in range(steps):
            for stage in range(4):
                rk4_second_order_stage(stage, h, state, stage_state, self._stages, pin.aba(model, data, q, v, tau))
            state[:] = stage_state
        return state

    def predict_numpy(self, x: np.ndarray, tau: np.ndarray, dt: float) -> np.ndarray:
        """:meth:`predict` in plain NumPy (:func:`~hydroarm.model.dynamics.integrator.rk4_step`)."""
        n, model, data = self.n, self.arm.model, self.data
        steps, h = inner_steps(dt, self.inner_step)

        def f(_t: float, y: np.ndarray) -> np.ndarray:
            return np.concatenate([y[n:], pin.aba(model, data, y[:n], y[n:], tau)])

        x = np.asarray(x, dtype=float)
        for _ in range(steps):
            x = rk4_step(f, 0.0, x, h)
        return x

    def step(self, t: float, x: np.ndarray, tau: np.ndarray, dt: float) -> tuple[np.ndarray, StepInfo]:
        """The plant's interface: ``(predict(x, tau, dt), StepInfo)`` with zero disturbance."""
        return self.predict(x, tau, dt), StepInfo(disturbance=self._zero.copy(), disturbance_start=self._zero.copy())

    # --- the one-step residual -----------------------------------------------------------
    def missed_force(self, q: np.ndarray, dv: np.ndarray, dt: float, product: str = "fixed") -> np.ndarray:
        """``M(q) dv / dt`` (n,) N m: the force that the velocity change ``dv`` (n,) rad/s over
        ``dt`` (s) takes beyond a prediction; the core of both residuals (module docstring).

        ``product`` (:data:`PRODUCTS`): ``"fixed"`` (default) the fixed-order product
        (:func:`~hydroarm.model.dynamics.fixed_order.matvec`: the same bits on any machine, for a learner
        that amplifies last bits), ``"blas"`` NumPy's ``@`` (the disturbance observers', kept so
        their numbers stay as published)."""
        if product not in PRODUCTS:
            raise ValueError(f"product = {product!r}: must be one of {', '.join(PRODUCTS)}")
        mass = self.mass_matrix(q)
        if product == "blas":
            return mass @ dv / dt
        return fixed_order.matvec(mass, dv) / dt

    def residual(self, y: np.ndarray, tau: np.ndarray, y_next: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
        """``(w (n,) N m, x_nominal (2n,))``: the one-step residual ``M(q) (v_next - v_nominal) / dt``
        of the measured step ``y -> y_next`` under ``tau`` over ``dt`` (s), and the nominal
        prediction ``x_nominal = predict(y, tau, dt)`` (fixed-order product: the GP learns from
        it, and amplifies last bits)."""
        n = self.n
        nominal = self.predict(y, tau, dt)
        return self.missed_force(y[:n], y_next[n:] - nominal[n:], dt), nominal

    def tde_residual(
        self, y: np.ndarray, u: np.ndarray, y_next: np.ndarray, dt: float, product: str = "fixed"
    ) -> np.ndarray:
        """The time-delay estimate's residual ``M(q) (v_next - v) / dt + h(q, v) - u`` (n,) N m of
        the measured step ``y -> y_next`` (2n,) under ``u`` (n,) N m over ``dt`` (s), M and h at
        y: the one-step residual against the explicit Euler prediction. ``product``: as in
        :meth:`missed_force`."""
        n = self.n
        q, v = y[:n], y[n:]
        return self.missed_force(q, y_next[n:] - v, dt, product) + self.nonlinear_effects(q, v) - u

    # --- linearisation ------------------------------------------------------------------
    def linearise(
        self, q: np.ndarray, v: np.ndarray, tau: np.ndarray, period: float, discretisation: str = "taylor2"
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(A (2n, 2n), B (2n, n), x_next (2n,))`` of the discrete dry model at (q, v, tau)
        with period T (s): ``discretisation`` ``"euler"`` or ``"taylor2"`` (module docstring)."""
        n = self.n
        a_mat = np.zeros((2 * n, 2 * n))
        b_mat = np.zeros((2 * n, n))
        x_next = self.linearise_into(q, v, tau, period, a_mat, b_mat, discretisation)
        return a_mat, b_mat, x_next

    def linearise_into(
        self, q, v, tau, period: float, a_mat: np.ndarray, b_mat: np.ndarray,
        discretisation: str = "taylor2", constant_blocks_set: bool = False,
    ) -> np.ndarray:  # fmt: skip
        """Write A and B of :meth:`linearise` into ``a_mat``, ``b_mat``; return ``x_next``.

        With ``constant_blocks_set`` (Euler only) the constant blocks (A's top rows
        ``[I, T I]``, B's top rows 0) are taken as already in place and only the
        bottom rows are written. The fill is compiled; :meth:`linearise_into_numpy`
        is its NumPy twin (Euler), bit for bit.
        """
        if discretisation not in DISCRETISATIONS:
            raise ConfigError(f"discretisation = {discretisation!r}: must be 'euler' or 'taylor2'")
        qdd, dqdd_dq, dqdd_dv, minv = self.forward_dynamics_derivatives(q, v, tau)
        euler = discretisation == "euler"
        x_next = _fill_linearisation(
            np.ascontiguousarray(q, dtype=float), np.ascontiguousarray(v, dtype=float),
            qdd, dqdd_dq, dqdd_dv, minv, float(period), a_mat, b_mat, not (euler and constant_blocks_set),
        )  # fmt: skip
        if not euler:
            _add_position_curvature(float(period), a_mat, b_mat)
            n = self.n
            x_next[:n] += 0.5 * period * (x_next[n:] - v)  # + T^2/2 q'', with T q'' = v+ - v
        return x_next

    def linearise_into_numpy(self, q, v, tau, period: float, a_mat, b_mat, constant_blocks_set: bool = False):
        """NumPy twin of :meth:`linearise_into` for the Euler step (tests compare the two)."""
        n = self.n
        qdd, dqdd_dq, dqdd_dv, minv = self.forward_dynamics_derivatives(q, v, tau)
        if not constant_blocks_set:
            a_mat[:n, :n] = np.eye(n)
            a_mat[:n, n:] = period * np.eye(n)
            b_mat[:n] = 0.0
        np.multiply(dqdd_dq, period, out=a_mat[n:, :n])
        np.multiply(dqdd_dv, period, out=a_mat[n:, n:])
        diagonal = np.arange(n)
        a_mat[n:, n:][diagonal, diagonal] += 1.0
        np.multiply(minv, period, out=b_mat[n:])
        return np.concatenate([q + period * v, v + period * qdd])

    def euler_step(self, x: np.ndarray, tau: np.ndarray, period: float) -> np.ndarray:
        """One explicit Euler step of the dry model: ``x + T [v, ABA(q, v, tau)]`` (2n,)."""
        n = self.n
        q, v = x[:n], x[n:]
        return np.concatenate([q + period * v, v + period * self.forward_dynamics(q, v, tau)])


@numba.njit(cache=True)
def _fill_linearisation(q, v, qdd, dqdd_dq, dqdd_dv, minv_upper, period, a_mat, b_mat, constant_blocks):
    """A's and B's bottom rows (and with ``constant_blocks`` their top rows) of the Euler step
    from ABA's derivatives (``M^-1`` symmetric: its upper triangle is read).
    Returns ``x_next = [q + T v, v + T q'']``.
    """  # pragma: no cover - compiled
    n = q.shape[0]
    x_next = np.empty(2 * n)
    for i in range(n):
        if constant_blocks:
            for j in range(n):
                a_mat[i, j] = 1.0 if i == j else 0.0
                a_mat[i, n + j] = period if i == j else 0.0
                b_mat[i, j] = 0.0
        for j in range(n):
            a_mat[n + i, j] = dqdd_dq[i, j] * period
            a_mat[n + i, n + j] = dqdd_dv[i, j] * period
            b_mat[n + i, j] = (minv_upper[i, j] if i <= j else minv_upper[j, i]) * period
        a_mat[n + i, n + i] += 1.0
        x_next[i] = q[i] + period * v[i]
        x_next[n + i] = v[i] + period * qdd[i]
    return x_next


@numba.njit(cache=True)
def _add_position_curvature(period, a_mat, b_mat):  # pragma: no cover - compiled
    """Turn Euler's A and B (all rows filled) into the second-order Taylor ones:
    position rows += T/2 x (velocity rows minus their identity block)."""
    n = b_mat.shape[1]
    half = 0.5 * period
    for i in range(n):
        for j in range(n):
            a_mat[i, j] += half * a_mat[n + i, j]
            a_mat[i, n + j] += half * (a_mat[n + i, n + j] - (1.0 if i == j else 0.0))
            b_mat[i, j] = half * b_mat[n + i, j]
