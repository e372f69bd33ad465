"""Reference trajectories: sums of sinusoids with analytic derivatives.

The paper's task (eq. 21, first six terms, SPEC section 4):
``q_r(t) = [3 cos t + 2 sin 2t, sin 2t, 2 cos t, 2 cos 2t, sin t, 3 cos t + 2 sin 2t]`` rad,
10 s, starting from rest at q = 0 (so the tracking error starts at q_r(0)).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SinusoidReference:
    """``q_i(t) = offset_i + sum_m cos_amp[i, m] cos(w[i, m] t) + sin_amp[i, m] sin(w[i, m] t)``.

    ``offset`` (n,) rad; ``cos_amp``, ``sin_amp`` (n, m) rad; ``omega`` (n, m) rad/s.
    """

    offset: np.ndarray
    cos_amp: np.ndarray
    sin_amp: np.ndarray
    omega: np.ndarray

    @property
    def n_joints(self) -> int:
        return int(self.offset.shape[0])

    def sample(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(q, v, a)`` at time(s) t (s): shape (n,) each for scalar t, else (len(t), n)."""
        times = np.asarray(t, dtype=float)
        tt = times[..., None, None]
        wt = self.omega * tt
        c, s = np.cos(wt), np.sin(wt)
        q = self.offset + np.sum(self.cos_amp * c + self.sin_amp * s, axis=-1)
        v = np.sum(self.omega * (-self.cos_amp * s + self.sin_amp * c), axis=-1)
        a = np.sum(-(self.omega**2) * (self.cos_amp * c + self.sin_amp * s), axis=-1)
        return q, v, a

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
    """Eq. (21) of Liu et al. 2023, first six terms (SPEC section 4)."""
    cos_amp = np.array([[3.0, 0.0], [0.0, 0.0], [2.0, 0.0], [0.0, 2.0], [0.0, 0.0], [3.0, 0.0]])
    sin_amp = np.array([[0.0, 2.0], [0.0, 1.0], [0.0, 0.0], [0.0, 0.0], [1.0, 0.0], [0.0, 2.0]])
    omega = np.array([[1.0, 2.0]] * 6)
    return SinusoidReference(np.zeros(6), cos_amp, sin_amp, omega)
