"""Fixed-step explicit integration of x' = f(t, x) (classic Runge-Kutta 4)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

Derivative = Callable[[float, np.ndarray], np.ndarray]


def rk4_step(f: Derivative, t: float, x: np.ndarray, h: float) -> np.ndarray:
    """One classic RK4 step of size h (s) from state x at time t; returns x(t + h)."""
    k1 = f(t, x)
    k2 = f(t + 0.5 * h, x + 0.5 * h * k1)
    k3 = f(t + 0.5 * h, x + 0.5 * h * k2)
    k4 = f(t + h, x + h * k3)
    return x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
