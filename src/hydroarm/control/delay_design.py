"""A closed-loop bandwidth chosen for the loop delay the controller is told (issue 32), and for a
delay margin it is not told of (:func:`delay_margin_weight`).

The ID-MPCs (:mod:`hydroarm.control.idmpc`) are told the loop delay d (periods, ``sensor.delay +
actuator.delay``) and handed the filtered state predicted across it on the dry model
(:class:`~hydroarm.control.estimator.FilteredController`). On the dry model that prediction is
exact and the loop is the undelayed one; but the wet arm is heavier than the dry model (the
water's added mass), so the acceleration it realises is g times the commanded one, g < 1, and
the moves still in flight are predicted g-wrong. Per joint, on the sampled double integrator
``x_{k+1} = A x_k + g B u_{k-d}`` with ``u_k = -K x_hat_{k+d|k}`` (the state predicted d steps on
the model under the d moves in flight), the loop's state is ``[x_k, u_{k-1}, ..., u_{k-d}]``
and :func:`told_delay_radius` its spectral radius. With the paper's weights (q_position 300,
q_velocity 0.01, T = 10 ms) and the default wrist weight R_a = 1e-6 it is stable for every g in
(0, 1] at d = 0, for g >= 0.56 at d = 1 and for g >= 0.70 at d = 2; the paper arm's joints
2-5 have g = 0.61-0.64 in water (:func:`wet_inertia_ratio`): two periods of delay diverge.

The design (``idmpc.inertia_margin`` = kappa, default :data:`INERTIA_MARGIN`): each joint's
acceleration weight is raised to the smallest one whose loop at the told delay keeps a
spectral radius of at most :data:`ROBUST_RADIUS` for every g in ``[g_j / kappa, 1]``, g_j the
joint's dry-to-wet inertia ratio of :func:`wet_inertia_ratio`: stable for a plant up to kappa
times heavier than the dry arm plus its own Morison added mass. At d = 0 every weight meets it
(nothing changes: the ideal loop and the paper mode are as before).
"""

from __future__ import annotations

import numpy as np

from hydroarm.control.linear import double_integrator, joint_lqr
from hydroarm.model.arm.description import Arm
from hydroarm.model.water.morison import Water, added_mass_matrix

INERTIA_MARGIN = 1.5
"""kappa (-): how much heavier than the dry arm plus its Morison added mass each joint's loop
must tolerate at the told delay. Measured on the paper arm (IDMPC, 16-bit encoder, published
friction, two periods of sensor delay, 10 s, 2026-12-04): kappa = 1.25 (the design model has no
filter; the position-only filter's lag takes some of the margin) diverged at 0.29 s, 1.5 did not."""

ROBUST_RADIUS = 0.95
"""The largest spectral radius (-) of a joint's loop over the plant gains it must tolerate."""

GAIN_SAMPLES = 12
"""Plant gains g checked, evenly spaced over ``[g_low, 1]`` (the radius is smooth in g)."""


def told_delay_radius(period: float, gain: np.ndarray, delay: int, plant_gain: float) -> float:
    """The spectral radius (-) of one joint's loop (module docstring): the LQR gain K (2,)
    (``gain``) acting on the state predicted ``delay`` periods ahead on the model, the plant
    realising ``plant_gain`` times the commanded acceleration, T = ``period`` (s)."""
    a_mat, b_vec = double_integrator(period)
    if delay == 0:
        return float(np.max(np.abs(np.linalg.eigvals(a_mat - plant_gain * np.outer(b_vec, gain)))))
    size = 2 + delay  # [x_k, u_{k-1}, ..., u_{k-d}]
    loop = np.zeros((size, size))
    loop[:2, :2] = a_mat
    loop[:2, 1 + delay] = plant_gain * b_vec  # the move of d steps ago acts now
    loop[2, :2] = -gain @ np.linalg.matrix_power(a_mat, delay)
    for i in range(delay):  # u_{k-1-i} (state index 2 + i) predicted forward i steps
        loop[2, 2 + i] = -gain @ np.linalg.matrix_power(a_mat, i) @ b_vec
    for k in range(3, size):
        loop[k, k - 1] = 1.0
    return float(np.max(np.abs(np.linalg.eigvals(loop))))


def worst_told_delay_radius(period: float, gain: np.ndarray, delay: int, gain_low: float) -> float:
    """The largest :func:`told_delay_radius` (-) over :data:`GAIN_SAMPLES` plant gains in
    ``[gain_low, 1]``."""
    gains = np.linspace(gain_low, 1.0, GAIN_SAMPLES)
    return max(told_delay_radius(period, gain, delay, float(g)) for g in gains)


def wet_inertia_ratio(arm: Arm) -> np.ndarray:
    """``g_j = M_jj(0) / (M_jj(0) + M_a,jj(0))`` (n,): each joint's dry inertia over its wet one at
    q = 0 (the configuration the authority weights use), with the Morison added mass of the
    arm's own links in the default water (rho 1000 kg/m^3, C_m = 2; the controller does not know
    the plant's water: this is its design assumption). 1 on a joint the water adds nothing to."""
    q = np.zeros(arm.n_joints)
    dry = np.diag(arm.mass_matrix(q))
    wet = dry + np.diag(added_mass_matrix(arm, Water(), q))
    return dry / wet


def delayed_observer_gain(delay: int) -> float:
    """The disturbance observer's gain L (-) for a loop told ``delay`` = d periods: behind the
    delay the observer takes the transition of d periods ago
    (:class:`~hydroarm.control.estimator.FilteredController`), so its estimate of a step
    disturbance settles as ``e_k = e_{k-1} - L e_{k-1-d}``, characteristic polynomial
    ``z^{d+1} - z^d + L``. Its spectral radius is smallest, ``d / (d + 1)`` (a double real root
    there), for::

        L* = d^d / (d + 1)^(d + 1)        (d = 0: 1, the TDE; 1: 1/4; 2: 4/27; 3: 27/256)

    a larger L rings (d = 1: the roots leave the real axis at radius sqrt(L); L >= 1 is
    unstable) and a smaller one is slower. Measured (paper arm, PI-IDMPC, 16-bit encoder,
    published friction, one period of sensor delay, 10 s, seed 0, 2026-12-04): its TDE remainder
    (L = 1) gave E_p 0.111 rad^2, L = 0.5 0.049, L* = 0.25 0.0345, 0.2 0.0330, 0.05 0.0364."""
    return float(delay**delay / (delay + 1) ** (delay + 1))


MARGIN_RADIUS = 0.9
"""The spectral radius (-) a joint's loop must keep with ``delay_margin`` periods of delay it is
not told of (:func:`delay_margin_weight`)."""


def delayed_radius(period: float, gain: np.ndarray, extra: int) -> float:
    """The spectral radius (-) of one joint's loop ``u_k = -K x_k`` on the sampled double integrator
    when the move acts ``extra`` periods late (a delay nothing predicts across); ``gain`` K (2,)."""
    a_mat, b_vec = double_integrator(period)
    size = 2 + extra
    loop = np.zeros((size, size))
    loop[:2, :2] = a_mat
    if extra == 0:
        loop[:2, :2] -= np.outer(b_vec, gain)
    else:
        loop[:2, 1 + extra] = b_vec  # the oldest move acts now
        loop[2, :2] = -gain
        for k in range(3, size):
            loop[k, k - 1] = 1.0
    return float(np.max(np.abs(np.linalg.eigvals(loop))))


def delay_margin_weight(period: float, q_position: float, q_velocity: float, margin: int) -> float:
    """The smallest acceleration weight R_a (s^4/rad^2) whose LQR
    (:func:`~hydroarm.control.linear.joint_lqr`) keeps the joint's loop at a spectral radius of at
    most :data:`MARGIN_RADIUS` with ``margin`` periods of delay it is not told of: the closed-loop
    bandwidth chosen for a stated delay margin. The radius first falls as R_a grows (the loop
    leaves the deadbeat law) and then rises towards 1 (a slow loop): the smallest R_a that meets
    it is found on a grid of 20 per decade from 1e-9 and refined by bisection. On the paper's
    weights (q_position 300, q_velocity 0.01, T = 10 ms) and a margin of one period it is 5.6e-5
    (the default wrist's 1e-6 has 1.33)."""

    def radius(weight: float) -> float:
        return delayed_radius(period, joint_lqr(period, q_position, q_velocity, weight)[1], margin)

    return _smallest_weight(radius, MARGIN_RADIUS, 1e-9, f"idmpc.delay_margin = {margin}")


def _smallest_weight(radius, limit: float, low: float, what: str) -> float:
    """The smallest weight >= ``low`` whose ``radius(weight)`` is at most ``limit``: a grid of 20
    per decade, then 60 bisections (the radius first falls as the weight grows, then rises)."""
    if radius(low) <= limit:
        return low
    for _ in range(400):
        high = low * 10.0**0.05
        if radius(high) <= limit:
            break
        low = high
    else:
        raise ValueError(f"{what}: no acceleration weight up to {high:.3g} meets it")
    for _ in range(60):
        middle = float(np.sqrt(low * high))
        low, high = (middle, high) if radius(middle) > limit else (low, middle)
    return high


def told_delay_weight(
    period: float, q_position: float, q_velocity: float, weight: float, delay: int, gain_low: float
) -> float:
    """The smallest acceleration weight R_a >= ``weight`` (s^4/rad^2) whose LQR keeps the joint's
    loop, told ``delay`` periods and predicted across them on the model, at a spectral radius of
    at most :data:`ROBUST_RADIUS` on every plant gain in
    ``[gain_low, 1]`` (:func:`worst_told_delay_radius`); ``weight``
    itself when ``delay`` is 0 or it meets it already."""
    if delay == 0:
        return weight

    def radius(r: float) -> float:
        return worst_told_delay_radius(period, joint_lqr(period, q_position, q_velocity, r)[1], delay, gain_low)

    return _smallest_weight(radius, ROBUST_RADIUS, weight, f"idmpc.loop_delay = {delay}")
