"""hydroarm on a ROS 2 graph (issue 31): the wire format against rosbags' (an independent
implementation of ROS 2's CDR), the nodes over Cyclone DDS on loopback, bad input dropped and
counted. Every participant here is bound to the loopback interface (no traffic leaves the machine)."""

# no `from __future__ import annotations`: Cyclone DDS reads the plain types' field types at run time

import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("cyclonedds")
rosbags_typesys = pytest.importorskip("rosbags.typesys")

from cyclonedds.domain import Domain, DomainParticipant  # noqa: E402
from cyclonedds.idl import IdlStruct  # noqa: E402
from cyclonedds.idl import types as t  # noqa: E402
from cyclonedds.qos import Policy, Qos  # noqa: E402
from cyclonedds.sub import DataReader  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402

from hydroarm.config import ConfigError  # noqa: E402
from hydroarm.model.arm.loading import load_arm  # noqa: E402
from hydroarm.ros2 import messages as m  # noqa: E402
from hydroarm.ros2.gate import CommandGate  # noqa: E402
from hydroarm.ros2.participant import Ros2Config, cyclone_xml  # noqa: E402
from hydroarm.sim.experiment import ExperimentConfig, run_experiment, with_overrides  # noqa: E402
from hydroarm.sim.rosbag import read_bag, trajectory_from_bag  # noqa: E402
from hydroarm.sim.runner import tracking_metrics  # noqa: E402

STORE = rosbags_typesys.get_typestore(rosbags_typesys.Stores.ROS2_HUMBLE)
LOOPBACK_XML = (
    '<CycloneDDS><Domain id="any"><General><Interfaces><NetworkInterface name="lo"/></Interfaces>'
    "<AllowMulticast>false</AllowMulticast></General><Discovery><ParticipantIndex>auto</ParticipantIndex>"
    '<MaxAutoParticipantIndex>32</MaxAutoParticipantIndex><Peers><Peer address="127.0.0.1"/></Peers>'
    "</Discovery></Domain></CycloneDDS>"
)
HYDROARM = [sys.executable, "-m", "hydroarm.cli"]


def _rosbags(msgtype, **fields):
    return STORE.types[msgtype](**fields)


def _stamp():
    return _rosbags("builtin_interfaces/msg/Time", sec=12, nanosec=345_000_000)


def _header():
    return _rosbags("std_msgs/msg/Header", stamp=_stamp(), frame_id="world")


def _transform():
    vector = _rosbags("geometry_msgs/msg/Vector3", x=0.1, y=-0.2, z=0.3)
    rotation = _rosbags("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=0.6, w=0.8)
    return _rosbags("geometry_msgs/msg/Transform", translation=vector, rotation=rotation)


def _cases():
    stamp, header = m.Time(12, 345_000_000), m.Header(m.Time(12, 345_000_000), "world")
    dim = m.MultiArrayDimension("joints", 3, 3)
    transform = m.Transform(m.Vector3(0.1, -0.2, 0.3), m.Quaternion(0.0, 0.0, 0.6, 0.8))
    stamped = m.TransformStamped(header, "link1", transform)
    array = np.array
    rdim = _rosbags("std_msgs/msg/MultiArrayDimension", label="joints", size=3, stride=3)
    rlayout = _rosbags("std_msgs/msg/MultiArrayLayout", dim=[rdim], data_offset=0)
    rstamped = _rosbags(
        "geometry_msgs/msg/TransformStamped", header=_header(), child_frame_id="link1", transform=_transform()
    )
    positions, velocities = [0.5, -1.25, 3.0], [0.0, 2.5, -7.0]
    return [
        (stamp, _stamp()),
        (header, _header()),
        (m.String("<robot/>"), _rosbags("std_msgs/msg/String", data="<robot/>")),
        (dim, rdim),
        (
            m.Float64MultiArray(m.MultiArrayLayout([dim], 0), [1.5, -2.0, 1e-9]),
            _rosbags("std_msgs/msg/Float64MultiArray", layout=rlayout, data=array([1.5, -2.0, 1e-9])),
        ),
        (
            m.JointState(header, ["j1", "j2", "j3"], positions, velocities, []),
            _rosbags(
                "sensor_msgs/msg/JointState",
                header=_header(),
                name=["j1", "j2", "j3"],
                position=array(positions),
                velocity=array(velocities),
                effort=array([], dtype=float),
            ),
        ),  # fmt: skip
        (m.Clock(stamp), _rosbags("rosgraph_msgs/msg/Clock", clock=_stamp())),
        (transform, _transform()),
        (stamped, rstamped),
        (m.TFMessage([stamped, stamped]), _rosbags("tf2_msgs/msg/TFMessage", transforms=[rstamped, rstamped])),
        *_vehicle_cases(header),
    ]


def _vehicle_cases(header):
    """The vehicle's messages (Imu, Odometry and their parts), covariances not all zero."""
    array = np.array
    point, quaternion = m.Point(1.0, -2.5, 0.25), m.Quaternion(0.0, 0.6, 0.0, 0.8)
    rpoint = _rosbags("geometry_msgs/msg/Point", x=1.0, y=-2.5, z=0.25)
    rquaternion = _rosbags("geometry_msgs/msg/Quaternion", x=0.0, y=0.6, z=0.0, w=0.8)
    pose = m.Pose(point, quaternion)
    rpose = _rosbags("geometry_msgs/msg/Pose", position=rpoint, orientation=rquaternion)
    linear, angular = m.Vector3(0.1, 0.2, -0.3), m.Vector3(-0.01, 0.02, 0.5)
    rlinear = _rosbags("geometry_msgs/msg/Vector3", x=0.1, y=0.2, z=-0.3)
    rangular = _rosbags("geometry_msgs/msg/Vector3", x=-0.01, y=0.02, z=0.5)
    twist, rtwist = m.Twist(linear, angular), _rosbags("geometry_msgs/msg/Twist", linear=rlinear, angular=rangular)
    cov36, cov9 = [0.001 * k for k in range(36)], [-1.0] + [0.0] * 8
    pwc = m.PoseWithCovariance(pose, cov36)
    rpwc = _rosbags("geometry_msgs/msg/PoseWithCovariance", pose=rpose, covariance=array(cov36))
    twc = m.TwistWithCovariance(twist, cov36)
    rtwc = _rosbags("geometry_msgs/msg/TwistWithCovariance", twist=rtwist, covariance=array(cov36))
    odometry = m.Odometry(header, "base_link", pwc, twc)
    rodometry = _rosbags("nav_msgs/msg/Odometry", header=_header(), child_frame_id="base_link", pose=rpwc, twist=rtwc)
    imu = m.Imu(header, quaternion, [0.0] * 9, angular, [0.5] * 9, linear, cov9)
    rimu = _rosbags(
        "sensor_msgs/msg/Imu", header=_header(), orientation=rquaternion, orientation_covariance=array([0.0] * 9),
        angular_velocity=rangular, angular_velocity_covariance=array([0.5] * 9), linear_acceleration=rlinear,
        linear_acceleration_covariance=array(cov9),
    )  # fmt: skip
    pairs = [(point, rpoint), (pose, rpose), (pwc, rpwc), (twist, rtwist), (twc, rtwc)]
    return [*pairs, (odometry, rodometry), (imu, rimu)]


@pytest.mark.parametrize("ours, theirs", _cases(), ids=lambda case: type(case).__name__)
def test_the_bytes_hydroarm_writes_are_rosbags_cdr(ours, theirs):
    """Every message type hydroarm puts on the graph: Cyclone DDS's serialisation of hydroarm's
    type equals rosbags' CDR of the same ROS 2 message, byte for byte, and reads back."""
    name = m.ROS_NAMES[type(ours)]
    assert name == theirs.__msgtype__
    expected = bytes(STORE.serialize_cdr(theirs, name))
    assert bytes(ours.serialize()) == expected
    assert type(ours).deserialize(expected) == ours


def test_ros2_names_and_topics():
    assert m.JointState.__idl_typename__ == "sensor_msgs::msg::dds_::JointState_"
    assert m.dds_topic("/effort_controller/commands") == "rt/effort_controller/commands"


def test_the_default_participant_stays_on_this_machine():
    """Safe by default: bound to the loopback interface, multicast off, peers on 127.0.0.1; another
    interface only when the setting names it (and then ROS 2's multicast discovery)."""
    xml = cyclone_xml(Ros2Config())
    assert '<NetworkInterface name="lo"/>' in xml and "<AllowMulticast>false</AllowMulticast>" in xml
    assert '<Peer address="127.0.0.1"/>' in xml
    opened = cyclone_xml(Ros2Config(interface="eth0"))
    assert '<NetworkInterface name="eth0"/>' in opened and "AllowMulticast" not in opened and "Peer" not in opened


@pytest.mark.parametrize(
    "key, value",
    [
        ("domain_id", 233), ("interface", "lo; rm"), ("on_stale", "brake"),
        ("thruster_controller_name", "effort_controller"),  # the arm's: two readers of one topic
        ("thruster_controller_name", "thrusters"),  # a fixed-base arm has no thrusters: never ignored
    ],
)  # fmt: skip
def test_bad_ros2_settings_are_refused_naming_the_field(key, value):
    result = subprocess.run(
        [*HYDROARM, "ros2", "sim", f"--{key.replace('_', '-')}", str(value), "--duration", "0.1"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert result.returncode == 2, result.stderr
    assert key in result.stderr and "Traceback" not in result.stderr


def test_the_command_gate_drops_and_counts_bad_commands():
    gate = CommandGate(3, timeout=0.1, on_stale="hold")
    np.testing.assert_array_equal(gate.torque(0.0), np.zeros(3))  # no command yet: zero torque
    assert not gate.offer([1.0, 2.0], 0.0)  # wrong length
    assert not gate.offer([1.0, float("nan"), 3.0], 0.0)  # not finite
    assert gate.offer([1.0, 2.0, 3.0], 0.0)
    np.testing.assert_array_equal(gate.torque(0.05), [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(gate.torque(0.5), [1.0, 2.0, 3.0])  # stale: held
    zero = CommandGate(3, timeout=0.1, on_stale="zero")
    zero.offer([1.0, 2.0, 3.0], 0.0)
    np.testing.assert_array_equal(zero.torque(0.5), np.zeros(3))  # stale: zero torque
    assert gate.counts == {
        "received": 3, "accepted": 1, "wrong_length": 1, "non_finite": 1, "stale": 1, "missing": 1
    }  # fmt: skip


# --- the nodes, in subprocesses on loopback --------------------------------------------------------


@dataclass
class PlainTime(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: t.int32 = 0
    nanosec: t.uint32 = 0


@dataclass
class PlainHeader(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: PlainTime = field(default_factory=PlainTime)
    frame_id: str = ""


@dataclass
class PlainJointState(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    header: PlainHeader = field(default_factory=PlainHeader)
    name: t.sequence[str] = field(default_factory=list)
    position: t.sequence[t.float64] = field(default_factory=list)
    velocity: t.sequence[t.float64] = field(default_factory=list)
    effort: t.sequence[t.float64] = field(default_factory=list)


def _domain_id() -> int:
    return 10 + os.getpid() % 50  # one per test process (<= 59; the tests add up to 170): xdist workers apart


def test_a_plain_cyclonedds_subscriber_receives_the_simulated_joint_states(tmp_path):
    """A subscriber written here with Cyclone DDS and ROS 2's type names alone (not hydroarm's
    classes) receives /joint_states from `hydroarm ros2 sim`: the arm's joint names, one state per
    control period of simulated time (stamps 10 ms apart)."""
    domain_id = _domain_id()
    domain = Domain(domain_id, config=LOOPBACK_XML)
    participant = DomainParticipant(domain_id)
    qos = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(100))
    reader = DataReader(participant, Topic(participant, "rt/joint_states", PlainJointState), qos=qos)
    command = [*HYDROARM, "ros2", "sim", "--set", "arm=ur5", "--duration", "0.5", "--domain-id", str(domain_id)]
    sim = subprocess.Popen(
        [*command, "--out", str(tmp_path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    states = []
    deadline = time.monotonic() + 120
    while sim.poll() is None and time.monotonic() < deadline:
        states += reader.take(N=100)
        time.sleep(0.01)
    states += reader.take(N=100)
    _, err = sim.communicate(timeout=30)
    assert sim.returncode == 0, err
    del domain
    states = [s for s in states if isinstance(s, PlainJointState)]  # not the writer's unregistration
    assert len(states) >= 40, len(states)  # 50 published, best effort on a loaded machine
    names = [str(name) for name in load_arm("ur5").model.names[1:]]  # the arm file's joint names
    assert all(list(s.name) == names for s in states), states[0].name
    stamps = np.array([s.header.stamp.sec + 1e-9 * s.header.stamp.nanosec for s in states])
    np.testing.assert_allclose(np.diff(stamps) / 0.01, np.round(np.diff(stamps) / 0.01), atol=1e-6)
    assert np.all(np.diff(stamps) > 0)


def test_two_processes_in_lockstep_are_the_in_process_run(tmp_path):
    """`hydroarm ros2 sim` and `hydroarm ros2 control --controller idmpc` on loopback in lockstep:
    E_p equal, number for number, to the runner's on the same settings and seed (the plant's noise
    included); every command accepted, none stale."""
    domain_id = _domain_id() + 50
    common = ["--set", "arm=paper", "--set", "duration=0.5", "--clock", "lockstep", "--domain-id", str(domain_id)]
    common += ["--command-timeout", "20"]
    bag = tmp_path / "bag"
    sim = subprocess.Popen(
        [*HYDROARM, "ros2", "sim", *common, "--out", str(tmp_path / "sim"), "--record", str(bag)],
        stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    # the controller stops 5 s after the last state (the simulator's own wait stays 20 s, for a loaded machine)
    controller = [*HYDROARM, "ros2", "control", "--controller", "idmpc", *common, "--command-timeout", "5"]
    controller += ["--duration", "300"]
    control = subprocess.run(
        [*controller, "--out", str(tmp_path / "control")], capture_output=True, text=True, timeout=400
    )
    _, err = sim.communicate(timeout=60)
    assert sim.returncode == 0 and control.returncode == 0, (err, control.stderr)
    result = json.loads((tmp_path / "sim" / "ros2_sim.json").read_text())
    assert result["counts"]["accepted"] == 50 and result["counts"]["stale"] == 0
    config = with_overrides(ExperimentConfig(), {"arm": "paper", "duration": 0.5})
    run = run_experiment(config, "idmpc", seed=0)
    assert result["Ep"] == tracking_metrics(run)["Ep"]
    # the recorded bag reads back as the run: the joint states on the wire are the measured ones
    recorded = trajectory_from_bag(bag)
    np.testing.assert_array_equal(recorded.x, run.y)
    np.testing.assert_array_equal(recorded.u, run.u)
    np.testing.assert_array_equal(recorded.q_ref, run.q_ref)
    np.testing.assert_allclose(recorded.t, run.t, rtol=0, atol=1e-9)  # stamps to the nanosecond
    counts = json.loads((tmp_path / "control" / "ros2_control.json").read_text())["counts"]
    # one per step, and maybe the state the run ended at (best effort, published as the sim exits)
    assert counts["commands"] in (50, 51) and counts["dropped_states"] == 0
    # the simulator stopped after its 0.5 s: the controller node stopped commanding and said so
    assert counts["timeouts"] == 1 and "stopped commanding" in control.stderr


@dataclass
class PlainVector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0


@dataclass
class PlainQuaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0
    w: t.float64 = 1.0


@dataclass
class PlainImu(IdlStruct, typename="sensor_msgs::msg::dds_::Imu_"):
    header: PlainHeader = field(default_factory=PlainHeader)
    orientation: PlainQuaternion = field(default_factory=PlainQuaternion)
    orientation_covariance: t.array[t.float64, 9] = field(default_factory=lambda: [0.0] * 9)
    angular_velocity: PlainVector3 = field(default_factory=PlainVector3)
    angular_velocity_covariance: t.array[t.float64, 9] = field(default_factory=lambda: [0.0] * 9)
    linear_acceleration: PlainVector3 = field(default_factory=PlainVector3)
    linear_acceleration_covariance: t.array[t.float64, 9] = field(default_factory=lambda: [0.0] * 9)


@dataclass
class PlainPose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: PlainVector3 = field(default_factory=PlainVector3)  # Point: the same three float64
    orientation: PlainQuaternion = field(default_factory=PlainQuaternion)


@dataclass
class PlainPoseWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    pose: PlainPose = field(default_factory=PlainPose)
    covariance: t.array[t.float64, 36] = field(default_factory=lambda: [0.0] * 36)


@dataclass
class PlainTwist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: PlainVector3 = field(default_factory=PlainVector3)
    angular: PlainVector3 = field(default_factory=PlainVector3)


@dataclass
class PlainTwistWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::TwistWithCovariance_"):
    twist: PlainTwist = field(default_factory=PlainTwist)
    covariance: t.array[t.float64, 36] = field(default_factory=lambda: [0.0] * 36)


@dataclass
class PlainOdometry(IdlStruct, typename="nav_msgs::msg::dds_::Odometry_"):
    header: PlainHeader = field(default_factory=PlainHeader)
    child_frame_id: str = ""
    pose: PlainPoseWithCovariance = field(default_factory=PlainPoseWithCovariance)
    twist: PlainTwistWithCovariance = field(default_factory=PlainTwistWithCovariance)


@dataclass
class PlainFloat64MultiArray(IdlStruct, typename="std_msgs::msg::dds_::Float64MultiArray_"):
    layout: m.MultiArrayLayout = field(default_factory=m.MultiArrayLayout)  # empty: its type is not read here
    data: t.sequence[t.float64] = field(default_factory=list)


VEHICLE = ["--set", "vehicle.name=bluerov2-heavy", "--set", "arm=mount"]


def test_a_plain_subscriber_receives_imu_and_odometry_from_the_vehicle_sim(tmp_path):
    """`hydroarm ros2 sim` on the vehicle: a subscriber written here with plain Cyclone DDS and ROS
    2's type names receives /imu and /odom, stamped on the control grid, in the documented frames,
    the IMU's orientation and rate those of the odometry of the same stamp, the specific force
    about +g along the body's z (level, slow); bad thruster commands from a plain writer are
    dropped and counted on the thrusters' gate, and the held good one goes stale."""
    domain_id = _domain_id() + 60
    domain = Domain(domain_id, config=LOOPBACK_XML)
    participant = DomainParticipant(domain_id)
    sensor = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(200))
    imu = DataReader(participant, Topic(participant, "rt/imu", PlainImu), qos=sensor)
    odom = DataReader(participant, Topic(participant, "rt/odom", PlainOdometry), qos=sensor)
    reliable = Qos(Policy.Reliability.Reliable(0), Policy.History.KeepLast(10))
    from cyclonedds.pub import DataWriter

    arm = DataWriter(participant, Topic(participant, "rt/effort_controller/commands", PlainFloat64MultiArray), reliable)
    topic = Topic(participant, "rt/thruster_controller/commands", PlainFloat64MultiArray)
    thrusts = DataWriter(participant, topic, reliable)
    command = [*HYDROARM, "ros2", "sim", *VEHICLE, "--duration", "1", "--domain-id", str(domain_id)]
    command += ["--command-timeout", "0.05", "--out", str(tmp_path)]
    sim = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    imus, odoms, sent = [], [], False
    deadline = time.monotonic() + 120
    while sim.poll() is None and time.monotonic() < deadline:
        imus += imu.take(N=200)
        odoms += odom.take(N=200)
        if not sent and thrusts.get_matched_subscriptions() and imus:
            for data in ([1.0, 2.0], [float("nan")] * 8, [0.0] * 8):  # wrong length, not finite, good
                thrusts.write(PlainFloat64MultiArray(data=data))
            sent = True
        time.sleep(0.005)
    imus += imu.take(N=200)
    odoms += odom.take(N=200)
    _, err = sim.communicate(timeout=30)
    assert sim.returncode == 0, err
    del arm, thrusts, domain
    imus = [s for s in imus if isinstance(s, PlainImu)]
    odoms = {_ns(s.header.stamp): s for s in odoms if isinstance(s, PlainOdometry)}
    assert len(imus) >= 60 and len(odoms) >= 60, (len(imus), len(odoms))  # 101 published, best effort
    assert all(s.header.frame_id == "base_link" for s in imus)
    assert all(s.header.frame_id == "world" and s.child_frame_id == "base_link" for s in odoms.values())
    assert all(_ns(s.header.stamp) % 10_000_000 == 0 for s in imus)  # on the 10 ms grid of simulated time
    paired = 0
    for sample in imus:
        other = odoms.get(_ns(sample.header.stamp))
        if other is None:
            continue
        paired += 1
        assert sample.orientation == other.pose.pose.orientation
        assert sample.angular_velocity == other.twist.twist.angular
        q = sample.orientation
        assert abs(q.x**2 + q.y**2 + q.z**2 + q.w**2 - 1.0) < 1e-9
        assert abs(sample.linear_acceleration.z - 9.81) < 1.0  # level and slow: gravity dominates
    assert paired >= 40
    thrusters = json.loads((tmp_path / "ros2_sim.json").read_text())["thruster_counts"]
    assert (thrusters["wrong_length"], thrusters["non_finite"], thrusters["accepted"]) == (1, 1, 1)
    # the held good command goes stale; "missing" (steps before the first thrust command) depends on
    # whether the writer's first sample beats the first step, which a loaded machine decides
    # (the gate's missing count: test_the_command_gate_drops_and_counts_bad_commands)
    assert thrusters["stale"] > 0 and thrusters["missing"] >= 0


def _ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def test_the_vehicle_in_lockstep_is_the_in_process_run_and_its_bag_reads_back(tmp_path):
    """`hydroarm ros2 sim` on the vehicle and `hydroarm ros2 control --controller smc` (the arm's SMC
    + the station keeper) in lockstep: E_p and the whole final state (vehicle pose, twist, thrust,
    arm) equal, number for number, to `hydroarm run`'s on the same settings; every arm and thrust
    command accepted. The bag recorded meanwhile reads back through compare's reader (the run's
    rows) and replay's (the joint states and the IMU's orientation: the vehicle's)."""
    domain_id = _domain_id() + 110
    # 1 s: the shortest log replay takes
    common = [*VEHICLE, "--set", "duration=1", "--clock", "lockstep", "--domain-id", str(domain_id)]
    bag = tmp_path / "bag"
    sim = subprocess.Popen(
        [*HYDROARM, "ros2", "sim", *common, "--command-timeout", "20", "--out", str(tmp_path), "--record", str(bag)],
        stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    controller = [*HYDROARM, "ros2", "control", "--controller", "smc", *common, "--command-timeout", "3"]
    control = subprocess.run([*controller, "--duration", "300"], capture_output=True, text=True, timeout=400)
    _, err = sim.communicate(timeout=60)
    assert sim.returncode == 0 and control.returncode == 0, (err, control.stderr)
    result = json.loads((tmp_path / "ros2_sim.json").read_text())
    config = with_overrides(ExperimentConfig(), {"vehicle.name": "bluerov2-heavy", "arm": "mount", "duration": 1.0})
    run = run_experiment(config, "smc", seed=0)
    assert result["Ep"] == tracking_metrics(run)["Ep"]
    assert result["final_state"] == run.meta["final_state"]
    for counts in (result["counts"], result["thruster_counts"]):
        assert counts["accepted"] == 100 and counts["stale"] == 0 and counts["received"] == 100
    recorded = trajectory_from_bag(bag)
    np.testing.assert_array_equal(recorded.x, run.y)  # the floating plant measures its true state
    np.testing.assert_array_equal(recorded.u, run.u)
    np.testing.assert_array_equal(recorded.q_ref, run.q_ref)
    log = read_bag(bag)  # what `hydroarm replay BAG --vehicle bluerov2-heavy` reads
    np.testing.assert_array_equal(log.joint_position[:100], run.q)
    np.testing.assert_array_equal(log.imu_quaternion[:100], run.extra["base_pose"][:, 3:7])
    assert log.joint_names == tuple(str(name) for name in load_arm("alpha5").model.names[1:])


def test_replay_refuses_a_fixed_arm_bag_naming_compare(tmp_path):
    """A fixed-base arm's recorded run has no IMU: replay exits 2 and names compare."""
    from hydroarm.model.arm.urdf_export import arm_to_urdf
    from hydroarm.ros2.record import BagRecorder

    recorder = BagRecorder(tmp_path / "bag")
    header = m.Header(m.Time(0, 0), "")
    recorder.write("/joint_states", m.JointState(header, ["j1"], [0.0], [0.0], [0.0]), 0.0)
    recorder.write("/hydroarm/joint_reference", m.JointState(header, ["j1"], [0.0], [0.0], []), 0.0)
    recorder.write("/robot_description", m.String(arm_to_urdf(load_arm("paper"))), 0.0)
    recorder.close()
    command = [*HYDROARM, "replay", str(tmp_path / "bag"), "--vehicle", "bluerov2-heavy", "--out", str(tmp_path / "r")]
    result = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert "hydroarm compare" in result.stderr and "no vehicle" in result.stderr


def test_the_controller_node_never_commands_blind(tmp_path):
    """No joint state ever arrives: the controller node publishes no command and says so."""
    command = [
        *HYDROARM,
        "ros2",
        "control",
        "--controller",
        "smc",
        "--wait",
        "1",
        "--domain-id",
        str(_domain_id() + 100),
    ]
    result = subprocess.run([*command, "--out", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "never commanded" in result.stderr
    counts = json.loads((tmp_path / "ros2_control.json").read_text())["counts"]
    assert counts["commands"] == 0 and counts["states"] == 0


def test_the_controller_node_drops_bad_states():
    """A state without one of the arm's joints, of mismatched lengths or with a NaN is dropped and
    counted; a good one in any joint order gives a command."""
    from hydroarm.ros2.control_node import ControlNode
    from hydroarm.sim.experiment import build_experiment

    config = with_overrides(ExperimentConfig(), {"arm": "paper", "duration": 0.1})
    node = ControlNode(build_experiment(config, "smc"), Ros2Config(domain_id=_domain_id() + 150))
    names = node.names
    header = m.Header(m.Time(0, 0), "")
    bad = [
        m.JointState(header, names[:-1], [0.0] * 5, [0.0] * 5, []),
        m.JointState(header, names, [0.0] * 6, [0.0] * 5, []),
        m.JointState(header, names, [0.0] * 5 + [float("nan")], [0.0] * 6, []),
    ]
    assert all(node.handle(state) is None for state in bad)
    good = node.handle(m.JointState(header, names[::-1], [0.1] * 6, [0.0] * 6, []))
    assert good is not None and good.shape == (6,)
    assert node.counts == {"states": 4, "commands": 1, "dropped_states": 3, "repeated_states": 0, "timeouts": 0}
    assert node.handle(m.JointState(header, names, [0.1] * 6, [0.0] * 6, [])) is None  # the same stamp again
    assert node.counts["repeated_states"] == 1


def test_the_docs_loop_figures_are_ros2_loop_json():
    """docs/ros2.md's measured loop (scripts/ros2_loop.py) is docs/data/ros2_loop.json's."""
    root = Path(__file__).resolve().parents[1]
    data = json.loads((root / "docs" / "data" / "ros2_loop.json").read_text())
    text = " ".join((root / "docs" / "ros2.md").read_text().split())
    wall, lockstep = data["wall"], data["lockstep"]
    assert lockstep["equal"] and lockstep["Ep"] == lockstep["in_process_Ep"] and not wall["diverged"]
    relative = max(abs(a - b) / b for a, b in zip(wall["Ep"], lockstep["in_process_Ep"]))
    for phrase in (
        f"{data['machine']['date']}, a {data['machine']['cpu_count']}-core x86-64 VM",
        f"{lockstep['counts']['accepted']} of 1000 commands accepted, {lockstep['counts']['stale']} stale",
        f"jitter median {wall['jitter_median_ms']:.2f} ms, p99 {wall['jitter_p99_ms']:.2f} ms, "
        f"max {wall['jitter_max_ms']:.2f} ms",
        f"median {wall['latency_median_ms']:.2f} ms, p99 {wall['latency_p99_ms']:.2f} ms, "
        f"max {wall['latency_max_ms']:.2f} ms; {wall['overruns']} overruns",
        f"within {relative:.0e} of the in-process run's",
    ):
        assert phrase in text, phrase


VETH, PEER, NETNS = "hxtest0", "hxtest1", "hydroarm-ros2-test"


@pytest.fixture(scope="module")
def private_link():
    """A virtual Ethernet link of this test's own: ``hxtest0`` here, its peer in a network namespace
    made for the test (no other host; multicast on it reaches that namespace only). Skipped where
    the machine does not let the test make one (not root, no iproute2)."""
    steps = [
        ["ip", "link", "add", VETH, "type", "veth", "peer", "name", PEER],
        ["ip", "netns", "add", NETNS],
        ["ip", "link", "set", PEER, "netns", NETNS],
        ["ip", "addr", "add", "10.254.254.1/30", "dev", VETH],
        ["ip", "link", "set", VETH, "up"],
        ["ip", "netns", "exec", NETNS, "ip", "link", "set", PEER, "up"],
    ]
    try:
        for step in steps:
            subprocess.run(step, check=True, capture_output=True, timeout=30)
    except (OSError, subprocess.CalledProcessError) as error:
        subprocess.run(["ip", "link", "del", VETH], capture_output=True)
        subprocess.run(["ip", "netns", "del", NETNS], capture_output=True)
        pytest.skip(f"cannot make a private veth link here: {error}")
    yield VETH
    subprocess.run(["ip", "link", "del", VETH], capture_output=True)
    subprocess.run(["ip", "netns", "del", NETNS], capture_output=True)


def _heard_on(interface: str, node_interface: str | None, domain_id: int) -> int:
    """Joint states a participant bound to ``interface`` (multicast discovery, ROS 2's default)
    hears from `hydroarm ros2 sim` started with ``--interface node_interface`` (None: its default)."""
    xml = (
        f'<CycloneDDS><Domain id="any"><General><Interfaces><NetworkInterface name="{interface}"/>'
        "</Interfaces></General></Domain></CycloneDDS>"
    )
    domain = Domain(domain_id, config=xml)
    participant = DomainParticipant(domain_id)
    reader = DataReader(
        participant, Topic(participant, "rt/joint_states", PlainJointState), qos=Qos(Policy.Reliability.BestEffort)
    )
    command = [*HYDROARM, "ros2", "sim", "--set", "duration=1", "--domain-id", str(domain_id), "--wait", "2"]
    command += [] if node_interface is None else ["--interface", node_interface]
    sim = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    heard, deadline = 0, time.monotonic() + 120
    while sim.poll() is None and time.monotonic() < deadline:
        heard += sum(isinstance(s, PlainJointState) for s in reader.take(N=100))
        time.sleep(0.01)
    _, err = sim.communicate(timeout=30)
    assert sim.returncode == 0, err
    del domain
    return heard


def test_a_default_node_is_not_discovered_from_another_interface(private_link):
    """Safe by default: a participant bound to another interface of the machine (the test's own
    veth link) hears nothing from a node with the defaults (loopback only); with --interface naming
    that interface, the node is discovered and heard (the setting opens it)."""
    base = _domain_id() + 160
    assert _heard_on(private_link, None, base) == 0
    assert _heard_on(private_link, private_link, base + 10) > 20


def test_tf_is_the_links_of_the_published_urdf():
    """/tf at a joint state: each link's frame in its parent's equals what Pinocchio computes from
    the URDF the node publishes on /robot_description (an independent parse of the exported file),
    with the URDF's link names."""
    import pinocchio as pin

    from hydroarm.model.arm.urdf_export import arm_to_urdf
    from hydroarm.ros2.sim_node import SimNode
    from hydroarm.sim.experiment import build_experiment

    experiment = build_experiment(with_overrides(ExperimentConfig(), {"arm": "ur5", "duration": 0.1}), None)
    node = SimNode(experiment, Ros2Config(domain_id=_domain_id() + 130))
    q = np.random.default_rng(3).uniform(-3.0, 3.0, experiment.arm.n_joints)
    message = node._transforms(m.Time(1, 0), q)
    urdf_model = pin.buildModelFromXML(arm_to_urdf(experiment.arm))
    urdf_data = urdf_model.createData()
    pin.forwardKinematics(urdf_model, urdf_data, q)
    assert [t.child_frame_id for t in message.transforms] == [f"link{j}" for j in range(1, 7)]
    assert message.transforms[0].header.frame_id == "base_link" and message.transforms[1].header.frame_id == "link1"
    for joint, stamped in enumerate(message.transforms, start=1):
        placement = urdf_data.liMi[urdf_model.getJointId(f"joint{joint}")]
        rotation = stamped.transform.rotation
        quaternion = pin.Quaternion(rotation.w, rotation.x, rotation.y, rotation.z)
        np.testing.assert_allclose(quaternion.toRotationMatrix(), placement.rotation, atol=1e-12)
        translation = stamped.transform.translation
        np.testing.assert_allclose([translation.x, translation.y, translation.z], placement.translation, atol=1e-12)


def test_the_vehicle_tf_chain_is_the_floating_system_kinematics():
    """On a vehicle, /tf's chain world -> base_link -> arm_base_link -> arm_link1 -> ... composes
    to each arm joint's world placement that Pinocchio computes on the whole floating system (the
    vehicle file's mount included), at a random pose and arm configuration."""
    import pinocchio as pin

    from hydroarm.ros2.sim_node import SimNode
    from hydroarm.sim.experiment import build_experiment

    config = with_overrides(ExperimentConfig(), {"vehicle.name": "bluerov2-heavy", "arm": "mount", "duration": 0.1})
    experiment = build_experiment(config, None)
    node = SimNode(experiment, Ros2Config(domain_id=_domain_id() + 140))
    model, n = experiment.uvms.model, node.n
    rng = np.random.default_rng(5)
    q = pin.randomConfiguration(model, -np.ones(model.nq), np.ones(model.nq))
    q[7:] = rng.uniform(-3.0, 3.0, n)
    x = np.concatenate([q, np.zeros(model.nv), np.zeros(node.plant.n_inputs - n)])
    stamp = m.Time(1, 0)
    chain = [*node.vehicle.transforms(stamp, x), *node._transforms(stamp, q[7:]).transforms]
    frames = {"world": pin.SE3.Identity()}
    for stamped in chain:
        r, p = stamped.transform.rotation, stamped.transform.translation
        local = pin.SE3(pin.Quaternion(r.w, r.x, r.y, r.z).toRotationMatrix(), np.array([p.x, p.y, p.z]))
        frames[stamped.child_frame_id] = frames[stamped.header.frame_id] * local
    data = model.createData()
    pin.forwardKinematics(model, data, q)
    for joint in range(1, n + 1):
        expected = data.oMi[joint + 1]  # joint 1 of the system: the vehicle's free flyer
        np.testing.assert_allclose(frames[f"arm_link{joint}"].homogeneous, expected.homogeneous, atol=1e-12)


def test_compare_reads_a_recorded_bag_as_a_run(tmp_path):
    """`hydroarm compare`'s reader on a bag of three states (one re-sent): row k is the state at
    t_k with the effort of the state after it; E_p the closed form over the two rows."""
    from hydroarm.ros2.record import BagRecorder
    from hydroarm.studies.compare import compare_rows, load_runs

    with pytest.raises(ConfigError, match="without .bag"):
        BagRecorder(tmp_path / "run.bag")
    recorder = BagRecorder(tmp_path / "run1")
    names = ["j1", "j2"]
    states = [([0.1, 0.2], [0.0, 0.0]), ([0.3, -0.1], [5.0, 6.0]), ([0.2, 0.0], [7.0, 8.0])]
    for k, (q, effort) in enumerate(states):
        header = m.Header(m.Time.of(0.01 * k), "")
        for _ in range(1 + (k == 1)):  # the second state twice, as a lockstep re-send reaches a recorder
            recorder.write("/joint_states", m.JointState(header, names, q, [0.0, 0.0], effort), 0.01 * k)
        recorder.write("/hydroarm/joint_reference", m.JointState(header, names, [0.0, 0.0], [0.0, 0.0]), 0.01 * k)
    recorder.close()
    (run,) = load_runs([tmp_path / "run1"])
    np.testing.assert_array_equal(run.trajectory.q, [[0.1, 0.2], [0.3, -0.1]])
    np.testing.assert_array_equal(run.trajectory.u, [[5.0, 6.0], [7.0, 8.0]])
    (row,) = compare_rows([run])
    np.testing.assert_allclose(row["Ep"], [(0.1**2 + 0.3**2) / 2, (0.2**2 + 0.1**2) / 2], rtol=1e-15)
