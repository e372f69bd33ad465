"""Reference trajectories: sums of sinusoids with analytic derivatives, and the vehicle
study's reach-and-return cycle (:class:`ReachReturn`).

The paper's task (eq. 21, first six terms, paper reading, section 4):
``q_r(t) = [3 cos t + 2 sin 2t, sin 2t, 2 cos t, 2 cos 2t, sin t, 3 cos t + 2 sin 2t]`` rad,
10 s, starting from rest at q = 0 (so the tracking error starts at q_r(0)).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import ClassVar

import numpy as np

from hydroarm.model.arm.description import Arm


@dataclass(frozen=True)
class SinusoidReference:
    """``q_i(t) = offset_i + sum_m cos_amp[i, m] cos(w[i, m] t) + sin_amp[i, m] sin(w[i, m] t)``.

    ``offset`` (n,) rad; ``cos_amp``, ``sin_amp`` (n, m) rad; ``omega`` (n, m) rad/s.
    """

    offset: np.ndarray
    cos_amp: np.ndarray
    sin_amp: np.ndarray
    omega: np.ndarray

    vectorised: ClassVar[bool] = True
    """``sample`` accepts an array of times (:class:`~hydroarm.control.interface.Reference`)."""

    @property
    def n_joints(self) -> int:
        return int(self.offset.shape[0])

    def sample(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(q, v, a)`` at time(s) t (s): shape (n,) each for scalar t, else (len(t), n).

        Every control step samples it (the runner and most controllers), so the terms that do
        not depend on t are kept (:attr:`_fixed_terms`) and the position's sum of terms serves the
        acceleration too: the same operations on the same values as writing each out, so the
        same bits (tests/test_references.py), at about half the cost."""
        wt = self.omega * (t if isinstance(t, float) else np.asarray(t, dtype=float)[..., None, None])
        c, s = np.cos(wt), np.sin(wt)
        minus_cos_amp, minus_omega_squared = self._fixed_terms
        position_terms = self.cos_amp * c + self.sin_amp * s
        total = np.add.reduce  # np.sum's own reduction, without its Python wrapper
        q = self.offset + total(position_terms, axis=-1)
        v = total(self.omega * (minus_cos_amp * s + self.sin_amp * c), axis=-1)
        a = total(minus_omega_squared * position_terms, axis=-1)
        return q, v, a

    @cached_property
    def _fixed_terms(self) -> tuple[np.ndarray, np.ndarray]:
        """``(-cos_amp, -omega^2)`` (n, m) each: the factors of :meth:`sample` that do not depend on t."""
        return -self.cos_amp, -(self.omega**2)

    def state(self, t: float) -> np.ndarray:
        """Reference state x_r = [q_r, v_r] at time t, shape (2n,)."""
        q, v, _ = self.sample(t)
        return np.concatenate([q, v])

    def scaled(self, scale: np.ndarray | float, offset: np.ndarray | None = None) -> SinusoidReference:
        """The same shape with joint amplitudes multiplied by ``scale`` (e.g. to fit joint limits)."""
        factor = np.broadcast_to(np.asarray(scale, dtype=float), self.offset.shape)[:, None]
        return SinusoidReference(
            offset=self.offset * factor[:, 0] if offset is None else np.asarray(offset, dtype=float),
            cos_amp=self.cos_amp * factor,
            sin_amp=self.sin_amp * factor,
            omega=self.omega,
        )


def paper_reference() -> SinusoidReference:
    """Eq. (21) of Liu et al. 2023, first six terms (paper reading, section 4)."""
    cos_amp = np.array([[3.0, 0.0], [0.0, 0.0], [2.0, 0.0], [0.0, 2.0], [0.0, 0.0], [3.0, 0.0]])
    sin_amp = np.array([[0.0, 2.0], [0.0, 1.0], [0.0, 0.0], [0.0, 0.0], [1.0, 0.0], [0.0, 2.0]])
    omega = np.array([[1.0, 2.0]] * 6)
    return SinusoidReference(np.zeros(6), cos_amp, sin_amp, omega)


def task_for_arm(arm: Arm) -> tuple[SinusoidReference, np.ndarray]:
    """The reference and the initial state (2n,) for ``arm``.

    A 6-joint arm without position limits (the paper's, UR5) gets the paper
    task from rest at q = 0. Other arms get the same shape (joint i follows the
    paper's joint i mod 6), scaled so that it stays within 80 % of each joint's
    range around its middle, starting at rest at the middle. Velocity limits are
    not enforced by the plant; the scaled task is a tracking test, not a
    certified motion.
    """
    paper = paper_reference()
    n = arm.n_joints
    if n == 6 and arm.position_limit is None:
        return paper, np.zeros(12)
    rows = [i % 6 for i in range(n)]
    base = SinusoidReference(paper.offset[rows], paper.cos_amp[rows], paper.sin_amp[rows], paper.omega[rows])
    if arm.position_limit is None:
        return base, np.zeros(2 * n)
    limits = np.asarray(arm.position_limit, dtype=float)
    finite = np.all(np.isfinite(limits), axis=1)
    middle = np.where(finite, 0.5 * (limits[:, 0] + limits[:, 1]), 0.0)
    half = np.where(finite, 0.5 * (limits[:, 1] - limits[:, 0]), np.inf)
    amplitude = np.sum(np.abs(base.cos_amp) + np.abs(base.sin_amp), axis=1)
    scale = np.minimum(1.0, 0.8 * half / np.maximum(amplitude, 1e-12))
    return base.scaled(scale, offset=middle), np.concatenate([middle, np.zeros(n)])


class ReachReturn:
    """Joint reference: from ``home`` to ``reach`` (n,) rad and back every ``period`` s (cosine
    blends, continuous acceleration at the ends of each leg), after ``start`` s at home.
    ``sample(t)`` takes a scalar time t (s) and returns ``(q, v, a)``, each (n,) (a controller
    that needs a horizon of times asks :func:`hydroarm.control.interface.sample_times`)."""

    def __init__(self, home, reach, period: float = 6.0, start: float = 1.0):
        self.home, self.reach = np.asarray(home, float), np.asarray(reach, float)
        self.period, self.start = period, start

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        tau = max(0.0, t - self.start) % self.period
        w = 2.0 * math.pi / self.period
        s = 0.5 * (1.0 - math.cos(w * tau))
        ds, dds = 0.5 * w * math.sin(w * tau), 0.5 * w * w * math.cos(w * tau)
        if t < self.start:
            ds = dds = 0.0
        delta = self.reach - self.home
        return self.home + s * delta, ds * delta, dds * delta
