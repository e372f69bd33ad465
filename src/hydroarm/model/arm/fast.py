"""The fixed-base plant, compiled: the whole RK4 control period in one call (``plant.compiled``).

The same equations as :class:`hydroarm.model.arm.plant.UnderwaterPlant` (docs/model.md), evaluated
body by body in the bodies' own frames (:mod:`hydroarm.model.arm.fast_kernels`) instead of
through three Pinocchio calls and the world Jacobians per RK4 stage:

* rigid body: RNEA (``C v + G``) and CRBA (``M``) on the revolute tree read from Pinocchio's model
  once (checked against ``pinocchio.crba``/``nonLinearEffects``/``aba``, tests/test_arm_fast.py);
* the water: every wetted cylinder through the strip kernels every plant shares
  (:func:`hydroarm.model.water.effects.cylinder_water`), in its body's frame, with
  ``plant.drag_points`` Gauss points per drag piece (default: the water's
  ``quadrature_points``, the reference's rule); its added-mass inertia is constant in that frame
  (:func:`~hydroarm.model.vehicle.fast.cylinder_added_inertia`) and joins the rigid body's in the CRBA;
  buoyancy, the current (the paper's joint acceleration and the uniform flow), the Reynolds drag
  and the axial drag as the reference evaluates them;
* the joint friction (viscous ``plant.friction`` and :class:`~hydroarm.model.real_loop.friction.FrictionConfig`),
  the held torque (zero-order hold), the RK4 bookkeeping and the disturbance record: the
  reference's, operation for operation where the arithmetic is the same.

At the reference's settings the two paths are the same mathematics in a different order of
round-off: the states differ by ~1e-14 after 10 s of a paper run (``scripts/arm_fast_accuracy.py``;
a test bounds a shorter run). :func:`hydroarm.model.arm.fast_kernels.batch_step_kernel` steps N
copies at once across the cores (:class:`BatchedArm`), each copy's numbers bit for bit its single step.
"""

from __future__ import annotations

import numba
import numpy as np
from numba.typed import List

from hydroarm.model.arm.description import Arm, revolute_axes
from hydroarm.model.arm.fast_kernels import (
    batch_step_kernel,
    evaluate,
    new_fast_arm,
    rigid_terms,
    scratch,
    step_kernel,
)
from hydroarm.model.dynamics.integrator import inner_steps
from hydroarm.model.real_loop.friction import FrictionConfig
from hydroarm.model.vehicle.fast import cylinder_added_inertia
from hydroarm.model.water.current import CurrentField
from hydroarm.model.water.morison import Water
from hydroarm.model.water.strips import StripGeometry


class FastArmDynamics:
    """The compiled handle (:class:`~hydroarm.model.arm.fast_kernels.FastArm`) of one (arm,
    water, friction) triple: the tree's arrays (``parents``, ``place_rotation``,
    ``place_translation``, ``axes``), the bodies' spatial inertias ``rigid`` and the water's
    added inertias ``added`` (nj, 6, 6), the strips (``geometry``, in the joints' frames as the
    reference's, with ``drag_points`` Gauss points; None: the water's ``quadrature_points``).
    ``uniform`` (N m s/rad): the viscous ``plant.friction``; ``friction``: the joint friction model."""

    def __init__(
        self,
        arm: Arm,
        water: Water | None = None,
        uniform: float = 0.0,
        friction: FrictionConfig | None = None,
        drag_points: int | None = None,
    ):
        water = water if water is not None else Water()
        friction = friction if friction is not None else FrictionConfig()
        model = arm.model
        n = arm.n_joints
        if model.nq != n or any(model.joints[i].idx_v != i - 1 for i in range(1, model.njoints)):
            raise ValueError(f"arm '{arm.name}': the compiled plant needs one revolute joint per coordinate, in order")
        self.arm, self.n = arm, n
        if drag_points is not None:
            water = water.model_copy(update={"quadrature_points": int(drag_points)})
        self.water = water
        nj = model.njoints
        self.parents = np.asarray(model.parents, dtype=np.int64)
        self.place_rotation = np.stack([model.jointPlacements[i].rotation for i in range(nj)])
        self.place_translation = np.stack([model.jointPlacements[i].translation for i in range(nj)])
        self.axes = revolute_axes(arm)
        self.rigid = np.stack([model.inertias[i].matrix() for i in range(nj)])
        self.geometry = StripGeometry(arm, water)
        geometry = self.geometry
        self.added = np.zeros((nj, 6, 6))
        if water.added_mass:
            for k in range(geometry.joint_ids.shape[0]):
                self.added[int(geometry.joint_ids[k])] += cylinder_added_inertia(
                    geometry.start[k], geometry.axis[k], geometry.length[k], geometry.mass_per_length[k]
                )
        self.strips = geometry.compiled
        self.gravity = np.asarray(model.gravity.linear, dtype=float).copy()
        if friction.active:
            arrays = tuple(np.ascontiguousarray(a, dtype=float) for a in friction.arrays(n))
        else:
            zero = np.zeros(n)
            arrays = (zero, zero, zero, np.ones(n), np.ones(n))
        tree = (self.parents, self.place_rotation, self.place_translation, self.axes, self.rigid,
                self.rigid + self.added)  # fmt: skip
        tree = tuple(np.ascontiguousarray(a) for a in tree)
        self.compiled = new_fast_arm(tree, self.gravity, self.strips, float(uniform), bool(friction.active), arrays)
        self._current = CurrentField(water.current, n)
        self._split = (None, None, 0, 0.0)

    # --- one instant ---------------------------------------------------------------------------
    def terms(self, q: np.ndarray, v: np.ndarray, t: float = 0.0):
        """``(M + M_A (n, n), nle (n,), f (n,), f_reynolds (n,))`` at (q, v) and time t: the
        rigid body's and the water's mass matrix, the rigid body's ``C v + G``, the water's
        generalised force but the added mass's acceleration term (``-h_A`` + buoyancy + axial
        drag + constant-C_d drag; the Reynolds drag apart)."""
        n = self.n
        q, v = np.ascontiguousarray(q, dtype=float), np.ascontiguousarray(v, dtype=float)
        water_velocity = self._current.at(float(t))[1]
        nle, force, drag, mass = np.empty(n), np.empty(n), np.empty(n), np.empty((n, n))
        rigid_terms(q, v, self.compiled, scratch(self.compiled), nle, force, drag, mass, water_velocity)
        return mass, nle, force, drag

    def dynamics(self, t: float, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(q'' (n,), disturbance (n,))`` at (t, q, v) under tau: the reference's
        :meth:`~hydroarm.model.arm.plant.UnderwaterPlant.dynamics`."""
        n = self.n
        acc, dist, drag = np.empty(n), np.empty(n), np.empty(n)
        q, v, tau = (np.ascontiguousarray(a, dtype=float) for a in (q, v, tau))
        evaluate(float(t), q, v, tau, self.compiled, scratch(self.compiled), acc, dist, drag)
        return acc, dist + drag

    # --- the control period --------------------------------------------------------------------
    def step(self, t: float, x: np.ndarray, tau: np.ndarray, dt: float, inner_step: float):
        """``(x_next (2n,), disturbance averaged (n,), first stage's disturbance (n,))``: RK4 in
        ``ceil(dt / inner_step)`` equal steps from (t, x) under the held tau."""
        last_dt, last_inner, steps, h = self._split
        if dt != last_dt or inner_step != last_inner:
            steps, h = inner_steps(dt, inner_step)
            self._split = (dt, inner_step, steps, h)
        return step_kernel(float(t), np.ascontiguousarray(x, dtype=float), np.ascontiguousarray(tau, dtype=float),
                           steps, h, self.compiled)  # fmt: skip


class BatchedArm:
    """N copies of a fixed-base arm stepped in one compiled call across the cores
    (:func:`~hydroarm.model.arm.fast_kernels.batch_step_kernel`). ``dynamics``: one
    :class:`FastArmDynamics` shared by every copy, or one per setting with ``which`` (N,) naming
    each copy's (different water, masses or friction)."""

    def __init__(self, dynamics: FastArmDynamics | list[FastArmDynamics], which: np.ndarray | None = None):
        self.dynamics = list(dynamics) if isinstance(dynamics, list | tuple) else [dynamics]
        sizes = {d.n for d in self.dynamics}
        if len(sizes) != 1:
            raise ValueError("BatchedArm: every copy's arm must have the same number of joints")
        self.n = sizes.pop()
        self._arms = List([d.compiled for d in self.dynamics])
        self.which = None if which is None else np.ascontiguousarray(which, dtype=np.int64)
        if self.which is not None and (self.which.min() < 0 or self.which.max() >= len(self.dynamics)):
            raise ValueError(f"BatchedArm: which must name one of the {len(self.dynamics)} settings")

    def step(self, t, x: np.ndarray, tau: np.ndarray, dt: float, inner_step: float):
        """``(x_next (N, 2n), disturbance (N, n), first stage's disturbance (N, n))`` for states x
        (N, 2n) under torques tau (N, n) from times t (scalar or (N,))."""
        x = np.ascontiguousarray(x, dtype=float)
        tau = np.ascontiguousarray(tau, dtype=float)
        count = x.shape[0]
        if x.shape != (count, 2 * self.n) or tau.shape != (count, self.n):
            raise ValueError(f"BatchedArm.step: x must be (N, {2 * self.n}) and tau (N, {self.n})")
        which = self.which if self.which is not None else np.zeros(count, dtype=np.int64)
        if which.shape[0] != count:
            raise ValueError(f"BatchedArm.step: {count} states for {which.shape[0]} copies")
        times = np.broadcast_to(np.asarray(t, dtype=float), (count,)).copy()
        steps, h = inner_steps(dt, inner_step)
        chunks = max(1, min(count, int(numba.get_num_threads())))
        return batch_step_kernel(times, x, tau, steps, h, self._arms, which, chunks)

    @staticmethod
    def threads() -> int:
        """numba's threads for the batched kernel."""
        return int(numba.get_num_threads())


__all__ = ["BatchedArm", "FastArmDynamics"]
