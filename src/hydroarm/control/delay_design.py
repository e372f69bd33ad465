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

The design decides "within the radius" by the Schur-Cohn test on the loop's characteristic
polynomial written out (:func:`loop_polynomial`, :func:`roots_within`), in scalar fixed-order
arithmetic. Until 2026-12-05 it compared LAPACK's eigenvalues of the loop matrix, whose last bits
follow the CPU's BLAS kernel: the weights' last bits then did too (OpenBLAS SkylakeX against
Haswell), and the real loop's GP-IDMPC run moved by 0.7 % in E_p.
"""

from __future__ import annotations

import math

import numpy as np

from hydroarm.control.linear import joint_lqr
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


def loop_polynomial(period: float, gain: np.ndarray, delay: int, plant_gain: float, predicted: bool) -> list[float]:
    """The characteristic polynomial (monic, highest power first, degree ``delay + 2``) of one
    joint's loop on the sampled double integrator, the plant realising ``plant_gain`` = g times the
    move of ``delay`` = d periods ago: ``predicted`` (:func:`told_delay_radius`'s loop) the LQR gain
    K (2,) on the state predicted d steps on the model under the d moves in flight, else
    (:func:`delayed_radius`'s) on the state itself. Written out from the loop's transfer function::

        p(z) = z^d (z - 1)^2 + (z - 1)^2 sum_i h_i z^(d-1-i) + g [(c . B)(z - 1) + c_0 T B_1]

    with ``c = K A^d`` and ``h_i = K A^i B`` (i < d) when predicted, ``c = K`` and no h otherwise
    (A = [[1, T], [0, 1]], B = [T^2/2, T]). Scalar arithmetic in a fixed order: the same bits on any
    machine (the design's decisions follow from it, :func:`_smallest_weight`)."""
    t, k0, k1 = float(period), float(gain[0]), float(gain[1])
    b0, b1 = 0.5 * t * t, t
    rising = [0.0] * (delay + 3)  # rising[p]: the coefficient of z^p
    rising[delay + 2], rising[delay + 1], rising[delay] = 1.0, -2.0, 1.0
    c0, c1 = (k0, k0 * (delay * t) + k1) if predicted else (k0, k1)
    for i in range(delay if predicted else 0):
        h = k0 * (b0 + (i * t) * b1) + k1 * b1  # K A^i B
        rising[delay + 1 - i] += h
        rising[delay - i] -= 2.0 * h
        rising[delay - 1 - i] += h
    dot = c0 * b0 + c1 * b1
    rising[1] += plant_gain * dot
    rising[0] += plant_gain * (c0 * t * b1 - dot)
    return rising[::-1]


def _radius(coefficients: list[float]) -> float:
    return float(np.max(np.abs(np.roots(coefficients))))


def roots_within(coefficients: list[float], limit: float) -> bool:
    """Whether every root of the polynomial (highest power first, nonzero leading coefficient) lies
    strictly within ``limit`` of 0: the Schur-Cohn test (Jury's table) of p(limit w) on the unit
    circle, in scalar fixed-order arithmetic. It agrees with the roots' largest modulus (LAPACK's
    eigenvalues of the companion matrix, whose last bits follow the CPU's BLAS kernel) but where
    that modulus is the limit to within its rounding (tests/test_told_delay.py)."""
    scaled, scale = [], 1.0
    for coefficient in coefficients:
        scaled.append(coefficient * scale)
        scale /= limit
    while len(scaled) > 1:
        reflection = scaled[-1] / scaled[0]
        if not abs(reflection) < 1.0:
            return False
        n = len(scaled) - 1
        scaled = [scaled[j] - reflection * scaled[n - j] for j in range(n)]
    return True


def told_delay_radius(period: float, gain: np.ndarray, delay: int, plant_gain: float) -> float:
    """The spectral radius (-) of one joint's loop (module docstring): the LQR gain K (2,)
    (``gain``) acting on the state predicted ``delay`` periods ahead on the model, the plant
    realising ``plant_gain`` times the commanded acceleration, T = ``period`` (s). The largest root
    of :func:`loop_polynomial` (for reports and tests; the design decides by :func:`roots_within`)."""
    return _radius(loop_polynomial(period, gain, delay, plant_gain, predicted=True))


def worst_told_delay_radius(period: float, gain: np.ndarray, delay: int, gain_low: float) -> float:
    """The largest :func:`told_delay_radius` (-) over :data:`GAIN_SAMPLES` plant gains in
    ``[gain_low, 1]``."""
    return max(told_delay_radius(period, gain, delay, float(g)) for g in np.linspace(gain_low, 1.0, GAIN_SAMPLES))


def _told_delay_holds(period: float, gain: np.ndarray, delay: int, gain_low: float) -> bool:
    """Whether the loop keeps every root within :data:`ROBUST_RADIUS` on all
    :data:`GAIN_SAMPLES` plant gains of :func:`worst_told_delay_radius` (fixed order)."""
    gains = np.linspace(gain_low, 1.0, GAIN_SAMPLES)
    return all(
        roots_within(loop_polynomial(period, gain, delay, float(g), predicted=True), ROBUST_RADIUS) for g in gains
    )


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


class DelayedEstimate:
    """What of a learned disturbance estimate is fed forward behind the told loop delay d.

    Behind d periods the learner's newest sample is of the transition d periods old, and what it
    feeds forward acts on transitions it sees d periods later. ``mode``:

    * ``"designed"``: the estimate w (n,) N m is fed forward through ``w_ff,k = w_ff,k-1 + L* (w_k -
      w_ff,k-1)`` from w_ff = 0, L* the :func:`delayed_observer_gain` (1/4 at d = 1, 4/27 at d = 2):
      a learner that answers its window at once is the TDE behind the delay (L = 1);
    * ``"none"``: nothing (:attr:`off`): the learner learns and its estimate is reported, the loop is
      the one without it.

    At d = 0 the estimate is fed forward as given, whatever the mode (the ideal loop, bit for bit).
    Measured on GP-IDMPC (docs/robustness.md, "GP-IDMPC behind a delay"): on arms with light wrists
    and no armature ``"designed"`` lowers E_p where the water is slow and leaves the band where it
    turns faster than the delayed estimate follows; hence ``"none"`` by default."""

    def __init__(self, delay: int, mode: str):
        if mode not in ("none", "designed"):
            raise ValueError(f"DelayedEstimate: mode = {mode!r}: give 'none' or 'designed'")
        self.delay = int(delay)
        self.off = self.delay > 0 and mode == "none"
        self.gain = delayed_observer_gain(self.delay) if self.delay > 0 else 1.0
        self._fed: np.ndarray | None = None

    def reset(self) -> None:
        self._fed = None

    def feed(self, estimate: np.ndarray) -> np.ndarray:
        """The estimate (n,) N m to feed forward this step, given the learner's ``estimate`` (n,)."""
        if self.delay == 0:
            return estimate
        if self.off:
            return np.zeros_like(estimate)
        fed = np.zeros_like(estimate) if self._fed is None else self._fed
        self._fed = fed + self.gain * (estimate - fed)
        return self._fed


MARGIN_RADIUS = 0.9
"""The spectral radius (-) a joint's loop must keep with ``delay_margin`` periods of delay it is
not told of (:func:`delay_margin_weight`)."""


def delayed_radius(period: float, gain: np.ndarray, extra: int) -> float:
    """The spectral radius (-) of one joint's loop ``u_k = -K x_k`` on the sampled double integrator
    when the move acts ``extra`` periods late (a delay nothing predicts across); ``gain`` K (2,).
    The largest root of :func:`loop_polynomial` (for reports and tests)."""
    return _radius(loop_polynomial(period, gain, extra, 1.0, predicted=False))


def delay_margin_weight(period: float, q_position: float, q_velocity: float, margin: int) -> float:
    """The smallest acceleration weight R_a (s^4/rad^2) whose LQR
    (:func:`~hydroarm.control.linear.joint_lqr`) keeps the joint's loop at a spectral radius of at
    most :data:`MARGIN_RADIUS` with ``margin`` periods of delay it is not told of: the closed-loop
    bandwidth chosen for a stated delay margin. The radius first falls as R_a grows (the loop
    leaves the deadbeat law) and then rises towards 1 (a slow loop): the smallest R_a that meets
    it is found on a grid of 20 per decade from 1e-9 and refined by bisection. On the paper's
    weights (q_position 300, q_velocity 0.01, T = 10 ms) and a margin of one period it is 5.6e-5
    (the default wrist's 1e-6 has 1.33)."""

    def holds(weight: float) -> bool:
        gain = joint_lqr(period, q_position, q_velocity, weight)[1]
        return roots_within(loop_polynomial(period, gain, margin, 1.0, predicted=False), MARGIN_RADIUS)

    return _smallest_weight(holds, 1e-9, f"idmpc.delay_margin = {margin}")


def _smallest_weight(holds, low: float, what: str) -> float:
    """The smallest weight >= ``low`` for which ``holds(weight)`` (its loop's roots within the
    radius asked for): a grid of 20 per decade, then 60 bisections (the radius first falls as the
    weight grows, then rises)."""
    if holds(low):
        return low
    for _ in range(400):
        high = low * 10.0**0.05
        if holds(high):
            break
        low = high
    else:
        raise ValueError(f"{what}: no acceleration weight up to {high:.3g} meets it")
    for _ in range(60):
        middle = math.sqrt(low * high)
        low, high = (low, middle) if holds(middle) else (middle, high)
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

    def holds(r: float) -> bool:
        return _told_delay_holds(period, joint_lqr(period, q_position, q_velocity, r)[1], delay, gain_low)

    return _smallest_weight(holds, weight, f"idmpc.loop_delay = {delay}")
