"""What a replay of a saved run needs, whatever draws it (:mod:`hydroarm.studies.animate`'s
matplotlib frames, :mod:`hydroarm.studies.viewer`'s browser scene): the trajectory, its arm and
the arm's reach. No plotting library is imported here, so the browser viewer starts without
matplotlib."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from hydroarm.config import ConfigError
from hydroarm.model.arm import Arm
from hydroarm.model.loading import load_arm
from hydroarm.sim.runner import Trajectory


def as_trajectory(trajectory: Trajectory | str | Path) -> Trajectory:
    """``trajectory`` itself, or the :class:`Trajectory` saved at that path (``.npz``)."""
    return trajectory if isinstance(trajectory, Trajectory) else Trajectory.load(trajectory)


def as_arm(arm: Arm | str | Path | None, traj: Trajectory) -> Arm:
    """The arm of a replay: ``arm`` itself, the arm it names, or (None) the run's own
    (``traj.meta["arm"]``); raises :class:`ConfigError` if its joints do not match the run's."""
    if isinstance(arm, Arm):
        found = arm
    else:
        found = load_arm(arm if arm is not None else traj.meta.get("arm", "paper"))
    if found.n_joints != traj.n_joints:
        raise ConfigError(
            f"arm '{found.name}' has {found.n_joints} joints, the trajectory {traj.n_joints}: pass the run's arm"
        )
    return found


def reach(
    arm: Arm, configurations: np.ndarray | None = None, samples: int = 200, seed: int = 0, most: int = 400
) -> float:
    """Largest distance (m) of any cylinder end from the base over ``configurations`` (K, n)
    (at most ``most`` of them, evenly spaced) and ``samples`` random ones within the joint
    limits (+-pi where unlimited), plus its radius."""
    rng = np.random.default_rng(seed)
    n = arm.n_joints
    low, high = np.full(n, -math.pi), np.full(n, math.pi)
    if arm.position_limit is not None:
        finite = np.isfinite(arm.position_limit)
        low = np.where(finite[:, 0], arm.position_limit[:, 0], low)
        high = np.where(finite[:, 1], arm.position_limit[:, 1], high)
    rows = [rng.uniform(low, high, size=(samples, n))]
    if configurations is not None:
        given = np.asarray(configurations, dtype=float).reshape(-1, n)
        rows.append(given[:: max(1, -(-len(given) // most))])
    radius = max((c.diameter / 2.0 for c in arm.cylinders), default=0.0)
    best = 0.0
    for q in np.concatenate(rows):
        ends = arm.cylinder_endpoints(q)
        best = max(best, float(np.max(np.linalg.norm(ends.reshape(-1, 3), axis=1))))
    return best + radius
