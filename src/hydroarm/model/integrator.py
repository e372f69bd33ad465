"""Fixed-step explicit integration of x' = f(t, x) (classic Runge-Kutta 4)."""

from __future__ import annotations

from collections.abc import Callable

import numba
import numpy as np

Derivative = Callable[[float, np.ndarray], np.ndarray]


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
