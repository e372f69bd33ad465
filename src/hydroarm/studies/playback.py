"""What a replay of a saved run needs, whatever draws it (:mod:`hydroarm.studies.animate`'s
matplotlib frames, :mod:`hydroarm.studies.viewer`'s browser scene): the trajectory, its arm, the
arm's reach and, for a vehicle-manipulator run, the vehicle's hull and poses
(:class:`VehicleMotion`). No plotting library is imported here, so the browser viewer starts
without matplotlib."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from hydroarm.config import ConfigError
from hydroarm.model.arm.description import Arm
from hydroarm.model.arm.loading import load_arm
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


def rotation(quaternion: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) of the unit quaternion (x, y, z, w) (Pinocchio's order)."""
    x, y, z, w = np.asarray(quaternion, dtype=float) / np.linalg.norm(quaternion)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


class VehicleMotion:
    """What a vehicle-manipulator run (``meta["vehicle"]`` and ``extra["base_pose"]``) adds to a
    replay: the vehicle's ``name``, the hull's half extents ``half`` (3,) m, the arm's mount in the
    body frame (``mount_rotation`` (3, 3), ``mount_translation`` (3,) m), the base poses ``poses``
    (K, 7: position m, quaternion x y z w) and the station-keeping ``target`` position (3,) m (the
    first pose when the run names none). Raises :class:`ConfigError` if the poses do not match the
    run's samples or the vehicle cannot be loaded."""

    def __init__(self, traj: Trajectory):
        from hydroarm.model.vehicle.description import load_vehicle

        vehicle = load_vehicle(traj.meta["vehicle"])
        self.name = vehicle.name
        self.half = np.asarray(vehicle.hull, dtype=float) / 2.0
        self.mount_rotation = np.asarray(vehicle.mount.rotation, dtype=float)
        self.mount_translation = np.asarray(vehicle.mount.translation, dtype=float)
        self.poses = np.asarray(traj.extra["base_pose"], dtype=float)
        if self.poses.shape != (len(traj.t), 7):
            raise ConfigError(f"base_pose has shape {self.poses.shape}, expected ({len(traj.t)}, 7)")
        self.target = np.asarray(traj.meta.get("target_pose", self.poses[0]), dtype=float)[:3]

    def arm_frame(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rotation (3, 3) and origin (3,) m of the arm's base frame in the world at base ``pose`` (7,)."""
        turn = rotation(pose[3:7])
        return turn @ self.mount_rotation, pose[:3] + turn @ self.mount_translation

    def corners(self, pose: np.ndarray) -> np.ndarray:
        """The hull box's 8 corners (8, 3) m in the world at base ``pose`` (7,), x slowest, z fastest."""
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=float)
        return (signs * self.half) @ rotation(pose[3:7]).T + pose[:3]

    def extent(self, arm: Arm, frames: np.ndarray, configurations: np.ndarray) -> float:
        """Half width (m) of a view about the target that holds samples ``frames``: the farthest
        drift, plus the farther of the hull's corner and the arm's reach from the body origin."""
        drift = float(np.max(np.linalg.norm(self.poses[frames, :3] - self.target, axis=1)))
        body = max(
            float(np.linalg.norm(self.half)), float(np.linalg.norm(self.mount_translation)) + reach(arm, configurations)
        )
        return drift + body

    def drift(self) -> np.ndarray:
        """The base's offset from the target (K, 3) m, world axes."""
        return self.poses[:, :3] - self.target

    def attitude_deg(self) -> np.ndarray:
        """Roll, pitch, yaw (K, 3) in degrees of every base pose (R = Rz(yaw) Ry(pitch) Rx(roll))."""
        x, y, z, w = (self.poses[:, 3:7] / np.linalg.norm(self.poses[:, 3:7], axis=1, keepdims=True)).T
        roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
        pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
        yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        return np.degrees(np.column_stack([roll, pitch, yaw]))


def vehicle_motion(traj: Trajectory) -> VehicleMotion | None:
    """The vehicle of a vehicle-manipulator run, None for a fixed-base one."""
    if traj.meta.get("vehicle") is None or "base_pose" not in traj.extra:
        return None
    return VehicleMotion(traj)
