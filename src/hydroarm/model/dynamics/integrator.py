"""Fixed-step explicit integration of x' = f(t, x) (classic Runge-Kutta 4), shared by every
plant and by the dry model.

:func:`inner_steps` splits a control period into the equal RK4 steps every integrator here
takes; :class:`StepInfo` is what one step of a joint-space model reports beside the next
state (the true plant's disturbance; zero for :class:`~hydroarm.model.dynamics.nominal.NominalModel`).
Both live here, not in the true plant's module, so that the dry model does not import the plant.
:func:`inner_step_setting` is the one definition of the ``inner_step`` setting (its range, unit
and meaning) that every plant's settings use: each system has its own (``plant.inner_step`` on
a fixed base, ``vehicle.plant.inner_step`` on a vehicle, the replay's ``inner_step``), with its
own default, and nothing else sets the step.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numba
import numpy as np
import pydantic

Derivative = Callable[[float, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class StepInfo:
    """What happened inside one plant step.

    ``disturbance`` (N m, (n,)): the generalised force beyond the dry model,
    averaged over the step with the RK4 weights (what a one-step residual can
    see); ``disturbance_start``: its value at the start of the step.
    """

    disturbance: np.ndarray
    disturbance_start: np.ndarray


INNER_STEP_RANGE: tuple[float, float] = (1e-5, 0.1)
"""s: the allowed ``inner_step`` of every plant (:func:`inner_step_setting`)."""


def inner_step_setting(default: float, plant: str) -> Any:
    """The ``inner_step`` field (s, in :data:`INNER_STEP_RANGE`) of ``plant``'s settings at
    ``default``: the longest RK4 step; the control period (or output period) is split into the
    fewest equal steps no longer than it (:func:`inner_steps`)."""
    low, high = INNER_STEP_RANGE
    return pydantic.Field(
        default,
        ge=low,
        le=high,
        description=f"longest RK4 step of {plant}: each period is split into the fewest equal steps no longer (s)",
    )


def inner_steps(dt: float, inner_step: float | None) -> tuple[int, float]:
    """``(count, h)``: ``dt`` (s) split into ``ceil(dt / inner_step)`` equal RK4 steps of h (s);
    one step of ``dt`` when ``inner_step`` is None."""
    if inner_step is None:
        return 1, dt
    steps = max(1, int(np.ceil(dt / inner_step - 1e-9)))
    return steps, dt / steps


def rk4_step(f: Derivative, t: float, x: np.ndarray, h: float) -> np.ndarray:
    """One classic RK4 step of size h (s) from state x at time t; returns x(t + h)."""
    k1 = f(t, x)
    k2 = f(t + 0.5 * h, x + 0.5 * h * k1)
    k3 = f(t + 0.5 * h, x + 0.5 * h * k2)
    k4 = f(t + h, x + h * k3)
    return x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


@numba.njit(cache=True)
def rk4_second_order_stage(stage, h, x, xs, ks, acceleration):  # pragma: no cover - compiled
    """One stage of :func:`rk4_step` for ``x = [q, v]``, ``x' = [v, a]``, with ``a`` computed outside.

    The caller evaluates the acceleration ``a`` (n,) at the stage state ``xs``
    (2n,); this stores ``ks[stage] = [v_s, a]`` and overwrites ``xs`` with the next
    stage's state (``x + h/2 k1``, ``x + h/2 k2``, ``x + h k3``) or, after stage 3,
    with ``x + h/6 (k1 + 2 k2 + 2 k3 + k4)``. The same operations in the same order
    as :func:`rk4_step` (bit-identical), without its ~15 small NumPy calls.
    """
    n = acceleration.shape[0]
    k = ks[stage]
    for i in range(n):
        k[i] = xs[n + i]
        k[n + i] = acceleration[i]
    if stage < 3:
        scale = h if stage == 2 else 0.5 * h
        for i in range(2 * n):
            xs[i] = x[i] + scale * k[i]
        return
    sixth = h / 6.0
    for i in range(2 * n):
        xs[i] = x[i] + sixth * (ks[0, i] + 2.0 * ks[1, i] + 2.0 * ks[2, i] + ks[3, i])


@numba.njit(cache=True)
def rk4_disturbance_stage(stage, h, x, xs, ks, acc, dist, dists, average, drag, with_drag):  # pragma: no cover
    """:func:`rk4_second_order_stage` for a plant that also reports its disturbance (n,): the one
    bookkeeping of the fixed-base arm's RK4, shared by the reference plant's compiled stage
    (:func:`hydroarm.model.arm.plant.rk4_stage_kernel`) and the fast plant's period
    (:func:`hydroarm.model.arm.fast_kernels.step_kernel`).

    Stores the stage's disturbance ``dists[stage] = dist`` (dists (4, n)), takes the RK4 stage of
    the acceleration ``acc`` (n,) (``ks`` (4, 2n), ``xs`` (2n,) the next stage's state); after
    the last stage (3) ``x`` (2n,) itself becomes the step's end state and ``average`` (n,)
    gains ``d1 + 2 d2 + 2 d3 + d4``. With
    ``with_drag`` (the Reynolds drag, joined to tau rather than to the water's force) the
    stage's ``drag`` (n,) is then added to ``dists[stage]`` (stages 0-2 enter the weighted sum
    with it), and stage 3's straight to ``average`` after the sum (the order the numbers were
    first made in; the 1-2-2-1 weights hold all the same).
    """
    n = acc.shape[0]
    for i in range(n):
        dists[stage, i] = dist[i]
    rk4_second_order_stage(stage, h, x, xs, ks, acc)
    if stage == 3:
        for i in range(2 * n):
            x[i] = xs[i]
        for i in range(n):
            average[i] += dists[0, i] + 2.0 * dists[1, i] + 2.0 * dists[2, i] + dists[3, i]
    if with_drag:
        for i in range(n):
            dists[stage, i] += drag[i]
            if stage == 3:
                average[i] += drag[i]
