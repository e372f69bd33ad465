"""ROS 2 messages on DDS, without a ROS installation: the IDL types hydroarm publishes and takes.

ROS 2 maps a message ``pkg/msg/Type`` to the DDS type ``pkg::msg::dds_::Type_`` and a topic
``/name`` to the DDS topic ``rt/name``; its wire format is XCDR1, little endian, which Cyclone DDS's
Python binding writes from these dataclasses. The bytes equal rosbags' serialisation of the same
message (an independent implementation of the ROS 2 wire format; ``tests/test_ros2.py``).

Each class's fields are its ROS 2 message's, in order, with the same types: ``builtin_interfaces``
Time; ``std_msgs`` Header, String, MultiArrayDimension, MultiArrayLayout, Float64MultiArray;
``sensor_msgs`` JointState; ``rosgraph_msgs`` Clock; ``geometry_msgs`` Vector3, Quaternion,
Transform, TransformStamped, Point, Pose, PoseWithCovariance, Twist, TwistWithCovariance;
``tf2_msgs`` TFMessage; ``nav_msgs`` Odometry; ``sensor_msgs`` Imu.
"""

# no `from __future__ import annotations`: Cyclone DDS reads the field types at run time
from dataclasses import dataclass, field

from cyclonedds.idl import IdlStruct
from cyclonedds.idl import types as t


def dds_topic(name: str) -> str:
    """The DDS topic of the ROS 2 topic ``name`` (``/joint_states`` -> ``rt/joint_states``)."""
    return "rt/" + name.lstrip("/")


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: t.int32 = 0
    nanosec: t.uint32 = 0

    @classmethod
    def of(cls, seconds: float) -> "Time":
        """The stamp of ``seconds`` (s, >= 0), rounded to the nanosecond."""
        total = round(seconds * 1e9)
        return cls(int(total // 1_000_000_000), int(total % 1_000_000_000))

    def seconds(self) -> float:
        return self.sec + self.nanosec * 1e-9


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class String(IdlStruct, typename="std_msgs::msg::dds_::String_"):
    data: str = ""


@dataclass
class MultiArrayDimension(IdlStruct, typename="std_msgs::msg::dds_::MultiArrayDimension_"):
    label: str = ""
    size: t.uint32 = 0
    stride: t.uint32 = 0


@dataclass
class MultiArrayLayout(IdlStruct, typename="std_msgs::msg::dds_::MultiArrayLayout_"):
    dim: t.sequence[MultiArrayDimension] = field(default_factory=list)
    data_offset: t.uint32 = 0


@dataclass
class Float64MultiArray(IdlStruct, typename="std_msgs::msg::dds_::Float64MultiArray_"):
    """What ros2_control's forward command controllers (``effort_controllers`` /
    ``forward_command_controller``) take on ``/<controller>/commands``: one value per joint, in the
    controller's joint order, the layout empty."""

    layout: MultiArrayLayout = field(default_factory=MultiArrayLayout)
    data: t.sequence[t.float64] = field(default_factory=list)


@dataclass
class JointState(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    header: Header = field(default_factory=Header)
    name: t.sequence[str] = field(default_factory=list)
    position: t.sequence[t.float64] = field(default_factory=list)
    velocity: t.sequence[t.float64] = field(default_factory=list)
    effort: t.sequence[t.float64] = field(default_factory=list)


@dataclass
class Clock(IdlStruct, typename="rosgraph_msgs::msg::dds_::Clock_"):
    clock: Time = field(default_factory=Time)


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0
    w: t.float64 = 1.0


@dataclass
class Transform(IdlStruct, typename="geometry_msgs::msg::dds_::Transform_"):
    translation: Vector3 = field(default_factory=Vector3)
    rotation: Quaternion = field(default_factory=Quaternion)


@dataclass
class TransformStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TransformStamped_"):
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    transform: Transform = field(default_factory=Transform)


@dataclass
class TFMessage(IdlStruct, typename="tf2_msgs::msg::dds_::TFMessage_"):
    transforms: t.sequence[TransformStamped] = field(default_factory=list)


@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0


@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


@dataclass
class PoseWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    pose: Pose = field(default_factory=Pose)
    covariance: t.array[t.float64, 36] = field(default_factory=lambda: [0.0] * 36)


@dataclass
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3 = field(default_factory=Vector3)
    angular: Vector3 = field(default_factory=Vector3)


@dataclass
class TwistWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::TwistWithCovariance_"):
    twist: Twist = field(default_factory=Twist)
    covariance: t.array[t.float64, 36] = field(default_factory=lambda: [0.0] * 36)


@dataclass
class Odometry(IdlStruct, typename="nav_msgs::msg::dds_::Odometry_"):
    """The pose in ``header.frame_id`` and the twist in ``child_frame_id`` (ROS's convention)."""

    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    pose: PoseWithCovariance = field(default_factory=PoseWithCovariance)
    twist: TwistWithCovariance = field(default_factory=TwistWithCovariance)


@dataclass
class Imu(IdlStruct, typename="sensor_msgs::msg::dds_::Imu_"):
    """A covariance whose first entry is -1 marks the quantity not measured (ROS's convention)."""

    header: Header = field(default_factory=Header)
    orientation: Quaternion = field(default_factory=Quaternion)
    orientation_covariance: t.array[t.float64, 9] = field(default_factory=lambda: [0.0] * 9)
    angular_velocity: Vector3 = field(default_factory=Vector3)
    angular_velocity_covariance: t.array[t.float64, 9] = field(default_factory=lambda: [0.0] * 9)
    linear_acceleration: Vector3 = field(default_factory=Vector3)
    linear_acceleration_covariance: t.array[t.float64, 9] = field(default_factory=lambda: [0.0] * 9)


ROS_NAMES: dict[type, str] = {
    Time: "builtin_interfaces/msg/Time",
    Header: "std_msgs/msg/Header",
    String: "std_msgs/msg/String",
    MultiArrayDimension: "std_msgs/msg/MultiArrayDimension",
    MultiArrayLayout: "std_msgs/msg/MultiArrayLayout",
    Float64MultiArray: "std_msgs/msg/Float64MultiArray",
    JointState: "sensor_msgs/msg/JointState",
    Clock: "rosgraph_msgs/msg/Clock",
    Vector3: "geometry_msgs/msg/Vector3",
    Quaternion: "geometry_msgs/msg/Quaternion",
    Transform: "geometry_msgs/msg/Transform",
    TransformStamped: "geometry_msgs/msg/TransformStamped",
    TFMessage: "tf2_msgs/msg/TFMessage",
    Point: "geometry_msgs/msg/Point",
    Pose: "geometry_msgs/msg/Pose",
    PoseWithCovariance: "geometry_msgs/msg/PoseWithCovariance",
    Twist: "geometry_msgs/msg/Twist",
    TwistWithCovariance: "geometry_msgs/msg/TwistWithCovariance",
    Odometry: "nav_msgs/msg/Odometry",
    Imu: "sensor_msgs/msg/Imu",
}
"""Each class's ROS 2 message name (``pkg/msg/Type``, as rosbags and ``ros2 topic`` write it)."""
