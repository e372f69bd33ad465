"""The ID-MPC's one torque map over its box (issue 32's review debt): ``held_torque`` over
``torque_box()`` replaced two near-copies, the map within the torque limits ``(-limit, limit)``
and the one within the drives' rate box. The paper's numbers and every controller's metrics were
made with the first, so in the limits' box the one map must give its bits exactly, in every mode,
flags included; in a rate box it gives the second's. The two maps as they were are kept here as
oracles (:func:`_symmetric_map`, :func:`_box_map`, verbatim but for taking the pieces as
arguments); a controller told a rate box that holds the limits gives the bits of one never told."""

from __future__ import annotations

import numpy as np
import pytest

from hydroarm.control.idmpc import IDMPCConfig, InverseDynamicsMPC
from hydroarm.control.idmpc_limits import allocate, box_allocate, held_torque
from hydroarm.model.dynamics import fixed_order

MODES = ("qp", "allocation", "clip")


def _product(mass, acceleration):
    """``M a`` as the maps form it since 2026-12-05: in fixed order (no BLAS: the flagship's run
    the same under any BLAS kernel), where the oracles had ``@``."""
    return fixed_order.matvec(np.ascontiguousarray(mass), np.ascontiguousarray(acceleration))


LIMIT = np.array([60.0, 60.0, 40.0, 5.0, 5.0, 5.0])  # N m: the paper arm, held tight so that it saturates


def _symmetric_map(limits, mass, bias, acceleration, limit, constrained):
    """``InverseDynamicsMPC.limited_torque`` without a rate told, as at d7305c4."""
    if limits == "clip":
        tau = _product(mass, acceleration) + bias
        clipped = np.clip(tau, -limit, limit)
        return clipped, acceleration, clipped != tau
    if limits == "qp":
        tau = _product(mass, acceleration) + bias
        if np.all(np.abs(tau) <= limit):
            return tau, acceleration, np.zeros(tau.shape[0], dtype=bool)
        a = constrained()
        if a is not None:
            tau = _product(mass, a) + bias
            clipped = np.clip(tau, -limit, limit)
            return clipped, a, np.abs(tau) >= limit * (1.0 - 1e-9)
    return allocate(mass, bias, acceleration, limit)


def _box_map(limits, mass, bias, acceleration, lower, upper, constrained):
    """``drive_limits.rate_limited_torque`` (the rate told) with its ``box_allocate``, as at d7305c4."""
    tau = _product(mass, acceleration) + bias
    fits = bool(np.all((tau >= lower) & (tau <= upper)))
    if fits and limits != "qp":
        return tau, acceleration, np.zeros(tau.shape[0], dtype=bool)
    if limits == "clip":
        clipped = np.clip(tau, lower, upper)
        return clipped, acceleration, clipped != tau
    if limits == "qp":
        a = constrained()
        if a is not None:
            tau = _product(mass, a) + bias
            clipped = np.clip(tau, lower, upper)
            tight = 1e-9 * np.maximum(np.abs(lower), np.abs(upper))
            return clipped, a, (tau <= lower + tight) | (tau >= upper - tight)
    centre = 0.5 * (lower + upper)
    tau, a, saturated = allocate(mass, bias - centre, acceleration, 0.5 * (upper - lower))
    return np.clip(tau + centre, lower, upper), a, saturated


def _problems(paper_arm, count, seed):
    """``(mass, bias, planned, qp's acceleration)``: random states of the paper arm whose planned
    torque mostly leaves ``LIMIT`` (and a QP's answer whose torque lands on and near its bounds)."""
    rng = np.random.default_rng(seed)
    for k in range(count):
        q, v = rng.normal(size=6) * 2.0, rng.normal(size=6) * 3.0
        mass = paper_arm.mass_matrix(q)
        bias = paper_arm.nonlinear_effects(q, v) - rng.normal(scale=5.0, size=6)
        planned = rng.normal(scale=[1.0, 100.0, 1e3][k % 3], size=6)
        # the QP's torque: on a bound (to rounding), a bit inside, or inside
        target = np.clip(mass @ planned + bias, -LIMIT, LIMIT) * rng.choice([1.0, 1 - 1e-10, 0.5], 6)
        yield mass, bias, planned, np.linalg.solve(mass, target - bias)


def _same_bits(got, expected):
    for g, e in zip(got, expected, strict=True):
        assert np.asarray(g).dtype == np.asarray(e).dtype
        assert np.asarray(g).tobytes() == np.asarray(e).tobytes()


@pytest.mark.parametrize("limits", [*MODES, "qp-failed"])
def test_in_the_limits_box_the_one_map_gives_the_symmetric_maps_bits(paper_arm, limits):
    """Every mode (and a QP whose solver failed), 300 random problems, most saturated."""
    mode, failed = limits.removesuffix("-failed"), limits.endswith("-failed")
    saturated = 0
    for mass, bias, planned, qp_answer in _problems(paper_arm, 300, seed=len(limits)):

        def constrained(qp_answer=qp_answer):
            return None if failed else qp_answer

        got = held_torque(mode, mass, bias, planned, -LIMIT, LIMIT, constrained)
        _same_bits(got, _symmetric_map(mode, mass, bias, planned, LIMIT, constrained))
        saturated += bool(got[2].any())
    assert saturated > 150  # the problems do saturate


def test_the_saturation_flag_at_its_threshold_and_for_non_finite_torques():
    """The QP's flag ``|tau| >= limit (1 - 1e-9)`` to the last bit: torques one ulp either side of
    the threshold, on the bound, past it, NaN and infinite (M = I, a = 0: tau = bias exactly)."""
    limit = np.array([60.0, 5.0, 0.3, 1234.5678, 7e-3, 1.0])
    threshold = limit * (1.0 - 1e-9)
    columns = [
        threshold, np.nextafter(threshold, 0.0), np.nextafter(threshold, np.inf), limit, -threshold,
        np.nextafter(-threshold, 0.0), np.nextafter(-threshold, -np.inf), 2.0 * limit, np.full(6, np.nan),
        np.full(6, np.inf), np.full(6, -np.inf), np.zeros(6),
    ]  # fmt: skip
    for tau in columns:
        bias = tau.copy()
        bias[0] = 2.0 * limit[0]  # one joint out of the box: the QP runs
        got = held_torque("qp", np.eye(6), bias, np.ones(6), -limit, limit, lambda: np.zeros(6))
        _same_bits(got, _symmetric_map("qp", np.eye(6), bias, np.ones(6), limit, lambda: np.zeros(6)))


def test_box_allocate_in_the_limits_box_is_allocate_bit_for_bit(paper_arm):
    for mass, bias, planned, _ in _problems(paper_arm, 200, seed=7):
        _same_bits(box_allocate(mass, bias, planned, -LIMIT, LIMIT), allocate(mass, bias, planned, LIMIT))
    # tau + 0.0 would turn a -0.0 into +0.0: allocate gives none, not even from -0.0 terms
    mass, zero = np.array([[2.0, 0.0], [0.0, 1.0]]), np.array([-0.0, -0.0])
    tau, _, _ = allocate(mass, zero, zero, np.ones(2))
    assert not np.signbit(tau).any()


@pytest.mark.parametrize("limits", MODES)
def test_in_a_rate_box_the_one_map_gives_the_rate_maps_bits(paper_arm, limits):
    """The drives' rate box (``tau_{-1} -+ r T`` within the limits), the QP run every step
    (``plan_always``): the rate map's torque and acceleration to the bit, and its flags (the
    tolerance is the same 1e-9 of the larger bound written so that the limits' box gives the
    symmetric flag exactly; the two forms may differ by an ulp of the bound, which no problem here meets)."""
    rng = np.random.default_rng(11)
    for mass, bias, planned, qp_answer in _problems(paper_arm, 300, seed=5):
        output = rng.uniform(-LIMIT, LIMIT)
        step = rng.uniform(0.01, 0.5, 6) * LIMIT
        lower, upper = np.clip(output - step, -LIMIT, LIMIT), np.clip(output + step, -LIMIT, LIMIT)
        got = held_torque(limits, mass, bias, planned, lower, upper, lambda a=qp_answer: a, plan_always=True)
        _same_bits(got, _box_map(limits, mass, bias, planned, lower, upper, lambda a=qp_answer: a))


@pytest.mark.parametrize("limits", MODES)
def test_a_controller_told_a_rate_box_holding_the_limits_gives_the_untold_bits(paper_arm, limits):
    """``limited_torque`` takes one path: told the drives' rate with a box that holds the limits
    (output 0, step 2 limit: ``torque_box()`` is ``(-limit, limit)``), a saturated step gives the
    bits of a controller never told (the QP's answer the same: the rate QP is another problem)."""
    told = InverseDynamicsMPC(paper_arm.with_torque_limit(LIMIT), IDMPCConfig(limits=limits, horizon=3))
    untold = InverseDynamicsMPC(paper_arm.with_torque_limit(LIMIT), IDMPCConfig(limits=limits, horizon=3))
    told.drive_limits(np.zeros(6), 2.0 * LIMIT)
    lower, upper = told.torque_box()
    _same_bits((lower, upper), (-LIMIT, LIMIT))
    checked = 0
    for mass, bias, planned, qp_answer in _problems(paper_arm, 60, seed=3):
        if np.all(np.abs(mass @ planned + bias) <= LIMIT):
            continue  # fits: told, the QP runs anyway (plan_always); not told, it does not
        for controller in (told, untold):
            controller.constrained_acceleration = lambda m, b, w, a=qp_answer: a
        w_hat = np.zeros(6)
        _same_bits(told.limited_torque(mass, bias, planned, w_hat), untold.limited_torque(mass, bias, planned, w_hat))
        checked += 1
    assert checked > 30
