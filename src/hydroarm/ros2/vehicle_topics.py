"""The vehicle's side of ``hydroarm ros2 sim`` (``vehicle.name`` set): what a vehicle-manipulator
simulator puts on the graph beside the arm's joint states, and the thruster commands it takes.

Frames (REP 105): ``world`` (the plant's inertial frame, z up, gravity -z), ``base_link`` (the
vehicle's body frame, at the plant's base), and the arm's URDF frames with the prefix ``arm_``
(``arm_base_link``, ``arm_link1``, ...: robot_state_publisher's ``frame_prefix``), its base at the
vehicle file's mount.

* ``/odom`` (``nav_msgs/Odometry``): the base's pose in ``world`` (``header.frame_id``) and its
  body twist in ``base_link`` (``child_frame_id``, as ROS states the twist), covariances zero (the
  plant's true state: the floating system has no sensor model);
* ``/imu`` (``sensor_msgs/Imu``, frame ``base_link``): the orientation in ``world`` (x y z w, as
  :mod:`hydroarm.sim.rosbag` writes it), the body angular velocity (rad/s) and the specific force
  (m/s^2: the acceleration minus gravity, in the body frame: +9.81 along the body's z at rest
  level), the acceleration at the state's time under the input held over the step that ended
  there; covariances zero (true values);
* ``/tf``: ``world -> base_link`` (the odometry's pose), ``base_link -> arm_base_link`` (the
  mount) and the arm's links;
* ``/<thruster_controller>/commands`` (``std_msgs/Float64MultiArray``): one thrust (N) per
  thruster in the vehicle file's thruster order, the ros2_control forward command controller's
  form, through its own :class:`~hydroarm.ros2.gate.CommandGate`.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from hydroarm.ros2.messages import (
    Header,
    Imu,
    Odometry,
    Point,
    Pose,
    PoseWithCovariance,
    Quaternion,
    Time,
    Transform,
    TransformStamped,
    Twist,
    TwistWithCovariance,
    Vector3,
)

WORLD, BASE, ARM_PREFIX = "world", "base_link", "arm_"


def _vector(values) -> Vector3:
    return Vector3(*(float(v) for v in values))


def _quaternion(xyzw) -> Quaternion:
    return Quaternion(*(float(v) for v in xyzw))


class VehicleState:
    """The vehicle's messages of the floating plant ``plant``
    (:class:`~hydroarm.model.vehicle.plant.UVMSPlant`: state ``[q (7 + n), v (6 + n), f]``) with the
    arm ``arm`` (the mounted arm the arm's URDF is exported from)."""

    def __init__(self, plant, arm):
        self.plant = plant
        self.layout = plant.uvms.layout  # the state's parts by name
        model = plant.uvms.model
        self.gravity = np.asarray(model.gravity.linear, dtype=float).copy()
        # base_link -> arm_base_link: the arm's first joint on the vehicle, less its own placement on the arm's base
        self.mount = model.jointPlacements[2] * arm.model.jointPlacements[1].inverse()

    def pose_twist(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The base's pose (7,: position m, quaternion x y z w) and body twist (6,: m/s, rad/s)."""
        return x[self.layout.base_pose], x[self.layout.base_velocity]

    def odometry(self, stamp: Time, x: np.ndarray) -> Odometry:
        pose, twist = self.pose_twist(x)
        body = Pose(Point(*(float(v) for v in pose[:3])), _quaternion(pose[3:7]))
        moving = Twist(_vector(twist[:3]), _vector(twist[3:6]))
        return Odometry(Header(stamp, WORLD), BASE, PoseWithCovariance(body), TwistWithCovariance(moving))

    def specific_force(self, t: float, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """What an accelerometer at the base's origin reads (3,) m/s^2, body frame: the classical
        acceleration ``dv/dt + omega x v`` less gravity turned into the body frame."""
        pose, twist = self.pose_twist(x)
        dv = self.plant.acceleration(t, x, u)[:3]
        rotation = pin.Quaternion(pose[6], *pose[3:6]).toRotationMatrix()
        return dv + np.cross(twist[3:6], twist[:3]) - rotation.T @ self.gravity

    def imu(self, stamp: Time, t: float, x: np.ndarray, u: np.ndarray) -> Imu:
        pose, twist = self.pose_twist(x)
        force = self.specific_force(t, x, u)
        return Imu(
            Header(stamp, BASE), _quaternion(pose[3:7]), angular_velocity=_vector(twist[3:6]),
            linear_acceleration=_vector(force),
        )  # fmt: skip

    def transforms(self, stamp: Time, x: np.ndarray) -> list[TransformStamped]:
        """``world -> base_link`` and ``base_link -> arm_base_link`` at the state ``x``."""
        pose, _ = self.pose_twist(x)
        base = Transform(_vector(pose[:3]), _quaternion(pose[3:7]))
        mx, my, mz, mw = pin.Quaternion(self.mount.rotation).coeffs()
        mount = Transform(_vector(self.mount.translation), _quaternion((mx, my, mz, mw)))
        return [
            TransformStamped(Header(stamp, WORLD), BASE, base),
            TransformStamped(Header(stamp, BASE), ARM_PREFIX + "base_link", mount),
        ]
