"""A physics-informed model of the water, learned online: recursive least squares on the Morison basis.

PI-IDMPC's estimate of the water (its settings: the ``water_model`` section), not the true water
the plants integrate (:mod:`hydroarm.model.water`).

The water's generalised force is linear in three coefficients per wetted cylinder
(:class:`~hydroarm.model.water.regressor.WaterRegressor`): ``w = Phi(q, v, a) theta``. The
learner keeps a Gaussian belief ``theta ~ N(theta_hat, P)`` and updates it with each observed
transition ``y -> y_next`` under the applied torque u (recursive least squares with exponential
forgetting, i.e. Bayesian linear regression whose old evidence fades by lambda per step)::

    r   = M(q) (v_next - v) / T + h(q, v) - u                     (the TDE residual, N m, (n,))
    Phi = Phi(q_mid, v_mid, (v_next - v) / T)                     (midpoint of the step)
    S   = lambda sigma^2 I + Phi P Phi^T,   K = P Phi^T S^-1
    theta_hat += K (r - Phi theta_hat),     P = (P - K Phi P) / lambda

then theta_hat is projected onto the box ``0 <= theta <= max_ratio x textbook`` (no negative
drag, added mass or volume, none beyond a bound: an estimate far outside it, fed through the
added-mass inertia into a loop with a time-delay estimate, breaks that loop's stability condition
``M_hat < 2 M_true``; measured: C_m = 16 fitted on a weakly exciting trajectory diverged).
``sigma^2`` ((N m)^2) is the residual's noise variance the learner assumes; ``P`` stays the
posterior covariance of theta (times the fading): :meth:`PhysicsInformedModel.variance` gives
the predicted force's variance. Forgetting is applied only in the directions the sample
excites (P is not inflated where Phi is zero), so an unexcited coefficient keeps its variance.

Prior (``prior = "textbook"``): C_d = 1 and C_m = 1 (a smooth circular cylinder, potential-flow
added mass) on every cylinder, and the displaced volume of the arm file (``buoyancy_kg`` or the
cylinder's): what a user knows before any data, not the plant's values. ``"zero"``: theta = 0.
The prior's standard deviation is ``prior_std`` times the textbook value of each coefficient.

A model is saved and loaded as JSON (:meth:`save`, :meth:`load`): theta_hat, P, the settings and
the arm's fingerprint (a model learned on one arm is refused on another).

Offline, :func:`fit_water` fits the same basis to a logged run (smoothing splines on the measured
positions, weighted least squares, instrumental variables against the measurement noise): an
identification run in still water gives C_d, C_m and the volumes (docs/controllers.md).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numba
import numpy as np
import pydantic
from scipy.interpolate import make_smoothing_spline

from hydroarm.config import ConfigError, FrozenModel
from hydroarm.control.observers import ObserverConfig
from hydroarm.model.arm.description import Arm
from hydroarm.model.dynamics import fixed_order as fixed
from hydroarm.model.dynamics.nominal import NominalModel
from hydroarm.model.water.morison import Water
from hydroarm.model.water.regressor import WaterRegressor

MODEL_FORMAT = "hydroarm-water-model-1"


class WaterModelConfig(FrozenModel):
    """Settings of the physics-informed water model (module docstring)."""

    forgetting: float = pydantic.Field(
        0.999, ge=0.9, le=1.0, description="lambda, the fading of old evidence per sample, 0.9 <= x <= 1 (-)"
    )
    noise_std: float = pydantic.Field(
        1.0, gt=0.0, le=1e4, description="sigma, the residual's noise the learner assumes per joint (N m)"
    )
    prior: Literal["textbook", "zero"] = pydantic.Field(
        "textbook", description="theta's prior mean: C_d = C_m = 1 and the arm file's volumes, or zero"
    )
    prior_std: float = pydantic.Field(
        1.0, gt=0.0, le=1e3, description="theta's prior std as a multiple of each textbook coefficient (-)"
    )
    max_acceleration: float = pydantic.Field(
        500.0, gt=0.0, le=1e6, description="a transition whose |dv/T| exceeds this is not learned (rad/s^2)"
    )
    max_ratio: float = pydantic.Field(
        3.0,
        ge=1.0,
        le=1e3,
        description="each coefficient is kept within [0, max_ratio x its textbook value] (projection) (-)",
    )
    remainder: ObserverConfig = pydantic.Field(
        ObserverConfig(kind="tde"),
        description="PI-IDMPC: the observer on what the model does not predict (the current, a mismatch) (section)",
    )


@numba.njit(cache=True)
def rls_kernel(phi, target, theta, p, noise_scale, lam):  # pragma: no cover - compiled
    """``(step (3C,), P' (3C, 3C), ok)`` of one RLS step (:meth:`PhysicsInformedModel.rls_step`,
    which adds ``step`` to theta and clips it): regressor ``phi`` (n, 3C), observed force ``target``
    (n,) N m, ``theta`` (3C,), covariance ``p`` (3C, 3C), ``noise_scale`` = lambda sigma^2, forgetting
    ``lam``. Fixed-order compiled products and a Cholesky solve (:mod:`hydroarm.model.dynamics.fixed_order`):
    BLAS and LAPACK round by their CPU's kernel, and the plan built on theta amplifies that. One
    compiled call: the same operations in the same order as the NumPy-level step it replaces (bit
    for bit), without its ~15 Python-level array calls (~50 us a control step)."""
    n = phi.shape[0]
    phi_t = np.ascontiguousarray(phi.T)
    p_phi = fixed.matmul(p, phi_t)
    innovation_cov = noise_scale * np.eye(n) + fixed.matmul(phi, p_phi)
    p_phi_t = np.ascontiguousarray(p_phi.T)
    solved, ok = fixed.cholesky_solve(innovation_cov, p_phi_t)
    if not ok:
        return np.zeros_like(theta), p, False
    gain = np.ascontiguousarray(solved.T)
    innovation = target - fixed.matvec(phi, theta)
    step = fixed.matvec(gain, innovation)
    p = p - fixed.matmul(gain, p_phi_t)
    if lam < 1.0:  # fade only the excited directions: P += (1/lam - 1) K S K^T
        p = p + (1.0 / lam - 1.0) * fixed.matmul(fixed.matmul(gain, innovation_cov), np.ascontiguousarray(gain.T))
    return step, 0.5 * (p + p.T), True


def arm_fingerprint(arm: Arm) -> str:
    """A short hash of what the basis depends on: the arm's kinematics and wetted cylinders."""
    parts = [arm.n_joints]
    for cylinder in arm.cylinders:
        parts += [cylinder.joint_id, *np.round(cylinder.start, 9), *np.round(cylinder.axis, 9)]
        parts += [round(cylinder.length, 9), round(cylinder.diameter, 9)]
    for placement in arm.model.jointPlacements:
        parts += list(np.round(placement.translation, 9)) + list(np.round(placement.rotation.ravel(), 9))
    return hashlib.sha256(json.dumps([float(p) for p in parts]).encode()).hexdigest()[:16]


class PhysicsInformedModel:
    """The Morison-basis water model of ``arm`` with its RLS learner (module docstring).

    ``water``: the density, gravity and quadrature the basis uses (its C_d, C_m are not read).
    :meth:`predict` (n,) N m at (q, v, a); :meth:`learn` one transition; :attr:`theta` (3C,),
    :attr:`covariance` (3C, 3C); :meth:`coefficients` C_d, C_m and volumes.
    """

    def __init__(self, arm: Arm, config: WaterModelConfig | None = None, water: Water | None = None):
        self.arm = arm
        self.config = config if config is not None else WaterModelConfig()
        self.regressor = WaterRegressor(arm, water)
        self.n = arm.n_joints
        self.nominal = NominalModel(arm, inner_step=None)  # own workspace
        textbook = self.regressor.parameters(self.regressor.water.model_copy(update={"cd": 1.0, "cm": 1.0}))
        self.textbook = textbook
        self._prior_mean = textbook.copy() if self.config.prior == "textbook" else np.zeros_like(textbook)
        scale = np.maximum(textbook, 1e-6 * max(float(textbook.max()), 1.0))
        self._prior_covariance = np.diag((self.config.prior_std * scale) ** 2)
        self._upper = self.config.max_ratio * scale
        self.reset()

    def reset(self) -> None:
        """Back to the prior."""
        self.theta = self._prior_mean.copy()
        self.covariance = self._prior_covariance.copy()
        self.samples = 0

    # --- prediction ---------------------------------------------------------------
    def predict(self, q: np.ndarray, v: np.ndarray, a: np.ndarray) -> np.ndarray:
        """The water's generalised force (n,) N m at q, v (n,) and acceleration a (n,)."""
        return self.regressor.predict(self.theta, q, v, a)

    def terms(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(M_A (n, n) kg m^2, f (n,) N m)``: the predicted water force is ``f - M_A a``."""
        return self.regressor.terms(self.theta, q, v)

    def terms_along(self, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`terms` at the N states of a plan, q, v (N, n): ``(M_A (N, n, n), f (N, n))``."""
        return self.regressor.terms_along(self.theta, q, v)

    # --- the estimator protocol (hydroarm.control.interface.DisturbanceEstimator) -----
    @property
    def n_samples(self) -> int:
        """The transitions learned since the last reset."""
        return self.samples

    def _split(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(q, v, a)`` (n,) each of the input ``x = [q, v, a]`` (3n,)."""
        x = np.asarray(x, dtype=float)
        if x.shape != (3 * self.n,):
            raise ValueError(f"the water model's input is [q, v, a]: {3 * self.n} values, got shape {x.shape}")
        n = self.n
        return x[:n], x[n : 2 * n], x[2 * n :]

    def mean(self, x: np.ndarray) -> np.ndarray:
        """The water's generalised force (n,) N m at ``x = [q, v, a]`` (3n,) (:meth:`predict`)."""
        return self.predict(*self._split(x))

    def variance(self, x: np.ndarray) -> np.ndarray:
        """The predicted force's variance (n,) (N m)^2 at ``x = [q, v, a]`` (3n,) under the belief on theta."""
        phi = self.regressor.basis(*self._split(x))
        return np.einsum("ip,pq,iq->i", phi, self.covariance, phi)

    def coefficients(self) -> dict[str, np.ndarray]:
        """C_d, C_m and the displaced volume (m^3) of every cylinder from theta (C,) each."""
        return self.regressor.physical(self.theta)

    # --- learning -----------------------------------------------------------------
    def residual(self, y: np.ndarray, u: np.ndarray, y_next: np.ndarray, period: float) -> np.ndarray:
        """The TDE residual ``M(q) (v_next - v) / T + h(q, v) - u`` (n,) N m of a transition
        (:meth:`~hydroarm.model.dynamics.nominal.NominalModel.tde_residual`, fixed-order product)."""
        return self.nominal.tde_residual(y, u, y_next, period)

    def transition_features(self, y: np.ndarray, y_next: np.ndarray, period: float):
        """``(q_mid, v_mid, a)``: the midpoint state and the mean acceleration of a transition."""
        n = self.n
        return 0.5 * (y[:n] + y_next[:n]), 0.5 * (y[n:] + y_next[n:]), (y_next[n:] - y[n:]) / period

    def update(self, x: np.ndarray, r: np.ndarray) -> bool:
        """Learn the observed force r (n,) N m at ``x = [q, v, a]`` (3n,): one RLS step on the
        Morison basis there (:meth:`rls_step`); False (nothing learned) as there."""
        return self.rls_step(self.regressor.basis(*self._split(x)), r)

    def rls_step(self, phi: np.ndarray, target: np.ndarray) -> bool:
        """One RLS step with the regressor ``phi`` (n, 3C) and the observed force ``target`` (n,)
        N m; False (nothing learned) for a non-finite sample, or if the innovation covariance is
        not positive definite (P has lost it)."""
        if not (np.all(np.isfinite(phi)) and np.all(np.isfinite(target))):
            return False
        lam = self.config.forgetting
        step, covariance, ok = rls_kernel(
            np.ascontiguousarray(phi, dtype=float), np.ascontiguousarray(target, dtype=float), self.theta,
            self.covariance, lam * self.config.noise_std**2, lam,
        )  # fmt: skip
        if not ok:  # S = lam sigma^2 I + phi P phi^T is positive definite unless P lost it
            return False
        self.theta = np.clip(self.theta + step, 0.0, self._upper)
        self.covariance = covariance
        self.samples += 1
        return True

    def learn(
        self, y: np.ndarray, u: np.ndarray, y_next: np.ndarray, period: float, acceleration: np.ndarray | None = None
    ) -> np.ndarray | None:
        """Learn the transition ``y -> y_next`` (2n,) under ``u`` (n,) over ``period`` (s); returns
        its residual (n,) N m, or None if the sample was refused (non-finite, or an acceleration
        beyond ``max_acceleration``: a blown-up or clipped step).

        ``acceleration`` (n,) rad/s^2: the acceleration the basis's added-mass columns take (the
        controller's commanded one: free of the sensor's noise, which in ``(v_next - v) / T``
        would bias the fit towards zero added mass); None: ``(v_next - v) / T``."""
        y, y_next, u = (np.asarray(x, dtype=float) for x in (y, y_next, u))
        q, v, a = self.transition_features(y, y_next, period)
        if not np.all(np.abs(a) <= self.config.max_acceleration):
            return None
        if acceleration is not None:
            a = np.asarray(acceleration, dtype=float)
        r = self.residual(y, u, y_next, period)
        return r if self.update(np.concatenate([q, v, a]), r) else None

    # --- memory -------------------------------------------------------------------
    def save(self, path: str | Path) -> None:
        """Write theta, P, the settings and the arm's fingerprint to ``path`` (JSON)."""
        payload = {
            "format": MODEL_FORMAT,
            "arm": arm_fingerprint(self.arm),
            "config": self.config.model_dump(mode="json"),
            "samples": self.samples,
            "theta": self.theta.tolist(),
            "covariance": self.covariance.tolist(),
            "coefficients": {k: v.tolist() for k, v in self.coefficients().items()},
        }
        Path(path).write_text(json.dumps(payload, indent=1))

    def load(self, path: str | Path) -> None:
        """Start from the model saved in ``path``; raises :class:`ConfigError` naming what is
        wrong (unreadable, another format, another arm, wrong sizes)."""
        source = Path(path)
        try:
            payload = json.loads(source.read_text())
        except (OSError, ValueError) as error:
            raise ConfigError(f"model file '{source}': cannot be read as JSON ({error})") from None
        if not isinstance(payload, dict) or payload.get("format") != MODEL_FORMAT:
            raise ConfigError(f"model file '{source}': not a hydroarm water model (format {MODEL_FORMAT!r})")
        if payload.get("arm") != arm_fingerprint(self.arm):
            raise ConfigError(f"model file '{source}': learned on another arm (its geometry differs from this one)")
        size = self.theta.shape[0]
        theta = np.asarray(payload.get("theta"), dtype=float)
        covariance = np.asarray(payload.get("covariance"), dtype=float)
        if theta.shape != (size,) or covariance.shape != (size, size) or not np.all(np.isfinite(covariance)):
            raise ConfigError(f"model file '{source}': theta must have {size} values and P {size} x {size}")
        if not np.all(np.isfinite(theta)):
            raise ConfigError(f"model file '{source}': theta is not finite")
        self.theta, self.covariance = theta, covariance
        self.samples = int(payload.get("samples", 0))


# --- offline identification from a logged run ------------------------------------------


@dataclass(frozen=True)
class WaterFit:
    """What :func:`fit_water` found.

    ``theta`` (3C,) the basis' coefficients; ``coefficients`` C_d, C_m and volume (m^3) (C,) each;
    ``identifiable`` (3C,) bool: excited by the data (False: in the basis' null space over the
    samples, left at the prior); ``residual_std`` (n,) N m per joint after the fit; ``samples``:
    the steps used.
    """

    theta: np.ndarray
    coefficients: dict[str, np.ndarray]
    identifiable: np.ndarray
    residual_std: np.ndarray
    samples: int


def fit_water(
    model: PhysicsInformedModel,
    t: np.ndarray,
    q: np.ndarray,
    u: np.ndarray,
    instruments: np.ndarray | None = None,
    trim: float = 0.5,
    reweight: int = 3,
) -> WaterFit:
    """Fit the Morison basis of ``model`` offline to a logged run of its arm.

    ``t`` (K,) s, evenly spaced; ``q`` (K, n) measured joint positions (rad), noisy or not;
    ``u`` (K, n) the torques (N m), each held from t_k to t_k+1. A smoothing spline per joint
    (:func:`scipy.interpolate.make_smoothing_spline`, its smoothing chosen by generalised
    cross-validation) gives q, q' and q'' at the middle of every step, where the step's residual
    ``M(q) q'' + h(q, q') - u_k`` is the water's force ``Phi(q, q', q'') theta``. The first and
    last ``trim`` seconds (the spline's ends) are left out. Least squares, each joint's rows
    weighted by the inverse of its residual's std (re-estimated ``reweight`` times).

    ``instruments`` (K, n): positions free of the measurement noise that the arm followed (the
    reference it tracked). With them the estimate is an instrumental-variable one: the basis at
    the instruments' states (splined the same way) multiplies both sides, so the noise that enters
    the residual and the basis together through q (errors in the variables, which pull the added
    mass towards zero) averages out. Directions the data does not excite keep ``model``'s prior
    mean.
    """
    t, q, u = (np.asarray(x, dtype=float) for x in (t, q, u))
    n = model.n
    if q.ndim != 2 or q.shape[1] != n or u.shape != q.shape or t.shape != (q.shape[0],):
        raise ValueError(f"t (K,), q and u (K, {n}) expected; got {t.shape}, {q.shape}, {u.shape}")
    period = float(np.median(np.diff(t)))
    middle = t[:-1] + 0.5 * period
    keep = (middle >= t[0] + trim) & (middle <= t[-1] - trim)
    if keep.sum() < model.regressor.n_parameters:
        raise ValueError(f"too few steps after trimming {trim} s at each end: {int(keep.sum())}")

    def splined(positions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        out = np.zeros((3, int(keep.sum()), n))
        for joint in range(n):
            spline = make_smoothing_spline(t, positions[:, joint])
            for order in range(3):
                out[order, :, joint] = spline.derivative(order)(middle[keep]) if order else spline(middle[keep])
        return out[0], out[1], out[2]

    nominal = model.nominal
    basis, target, basis_z = [], [], []
    states = splined(q)
    reference = splined(np.asarray(instruments, dtype=float)) if instruments is not None else None
    for k, u_k in enumerate(u[:-1][keep]):
        qk, vk, ak = states[0][k], states[1][k], states[2][k]
        target.append(nominal.inverse_dynamics(qk, vk, ak) - u_k)  # M(q) q'' + h(q, q') - u
        basis.append(model.regressor.basis(qk, vk, ak))
        if reference is not None:
            basis_z.append(model.regressor.basis(reference[0][k], reference[1][k], reference[2][k]))
    phi, r = np.concatenate(basis), np.concatenate(target)
    z = np.concatenate(basis_z) if reference is not None else phi
    _, singular, vt = np.linalg.svd(phi, full_matrices=False)
    null = vt[singular < 1e-9 * singular[0]]
    weights = np.ones(n)
    for _ in range(reweight + 1):
        w = np.tile(weights, len(target))[:, None]
        theta = np.linalg.pinv((z * w).T @ (phi * w), rcond=1e-9) @ ((z * w).T @ (r * w[:, 0]))
        residual = (r - phi @ theta).reshape(-1, n)
        weights = 1.0 / np.maximum(residual.std(axis=0), 1e-12)
    theta = theta - null.T @ (null @ theta) + null.T @ (null @ model._prior_mean)
    identifiable = np.abs(null).max(axis=0) < 1e-6 if len(null) else np.ones(theta.shape[0], dtype=bool)
    return WaterFit(
        theta=theta,
        coefficients=model.regressor.physical(theta),
        identifiable=identifiable,
        residual_std=residual.std(axis=0),
        samples=len(target),
    )
