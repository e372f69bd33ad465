"""ROS 2 bags in and out (``rosbags``, pure Python: no ROS install), as :class:`~hydroarm.sim.logs.TrialLog`.

Reading (:func:`read_bag`: an ``.mcap`` or ``.db3`` file, or a bag folder with
``metadata.yaml``; ROS 1 bags too, through ``rosbags.highlevel.AnyReader``): the first topic of
type ``sensor_msgs/msg/JointState`` (not hydroarm's own ``/hydroarm/...``) gives the joints (by
name; positions in rad), the first ``sensor_msgs/msg/Imu`` the IMU (orientation x y z w, angular
velocity rad/s) and the first ``geometry_msgs/msg/PoseStamped`` the motion capture. Times are
the messages' header stamps (s).

Writing (:func:`write_bag`): the same three topics (``/joint_states``, ``/imu``, ``/mocap/pose``)
into an MCAP bag (ROS 2 ``humble`` message definitions), plus, for a replayed run, the simulated
vehicle attitude as ``/hydroarm/vehicle_pose`` (PoseStamped): Foxglove and PlotJuggler open it.
A bag written from a log reads back to the same log (a test).

A bag that ``hydroarm ros2 sim --record`` wrote reads back as a run (:func:`trajectory_from_bag`,
what ``hydroarm compare`` reads): ``/joint_states`` and the task's ``/hydroarm/joint_reference``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hydroarm.sim.logs import LogError, TrialLog, _check_stream, _check_time

JOINT_STATE = "sensor_msgs/msg/JointState"
IMU = "sensor_msgs/msg/Imu"
POSE = "geometry_msgs/msg/PoseStamped"
REFERENCE_TOPIC = "/hydroarm/joint_reference"
"""The task's joint reference that ``hydroarm ros2 sim`` publishes (and records) beside the joint states."""


def _typestore():
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_HUMBLE)


def _stamp(header) -> float:
    return float(header.stamp.sec) + 1e-9 * float(header.stamp.nanosec)


def _open_bag(path: Path):
    """An open rosbags reader of the bag at ``path`` (ROS 2 or ROS 1); LogError if it cannot be read."""
    from rosbags.highlevel import AnyReader

    try:
        reader = AnyReader([path], default_typestore=_typestore())
        reader.open()
    except Exception as error:  # rosbags raises its own error types for unreadable bags
        raise LogError(f"{path}: not a readable ROS bag ({error})") from None
    return reader


def _connections_by_type(reader, source: str) -> dict[str, list]:
    """The bag's connections by message type; LogError naming what is missing for a replay (a
    fixed-base arm's bag, which has no IMU, is pointed to ``hydroarm compare``)."""
    by_type: dict[str, list] = {}
    for connection in reader.connections:
        by_type.setdefault(connection.msgtype, []).append(connection)
    for kind in (JOINT_STATE, IMU):
        if kind not in by_type:
            topics = ", ".join(f"{c.topic} ({c.msgtype})" for c in reader.connections) or "none"
            if kind == IMU and any(c.topic == REFERENCE_TOPIC for c in reader.connections):
                raise LogError(
                    f"{source}: a fixed-base arm's run recorded by hydroarm ros2 sim: no vehicle, no "
                    f"{IMU} topic to replay against; read it with hydroarm compare {source}"
                )
            raise LogError(f"{source}: no {kind} topic (topics: {topics})")
    return by_type


def read_bag(path: str | Path) -> TrialLog:
    """The trial in a ROS 2 (or ROS 1) bag (module docstring); LogError for a bag without the topics."""
    path = Path(path)
    source = str(path)
    reader = _open_bag(path)
    try:
        by_type = _connections_by_type(reader, source)
        joint_topics = [c for c in by_type[JOINT_STATE] if not c.topic.startswith("/hydroarm/")]
        joints = (joint_topics or by_type[JOINT_STATE])[0]
        names: tuple[str, ...] | None = None
        joint_rows, joint_time = [], []
        imu_time, imu_q, imu_w = [], [], []
        pose_time, pose_q = [], []
        poses = [c for c in by_type.get(POSE, []) if not c.topic.startswith("/hydroarm/")]
        pose = poses[0] if poses else None
        wanted = [joints, by_type[IMU][0]] + ([pose] if pose is not None else [])
        for connection, _, raw in reader.messages(connections=wanted):
            message = reader.deserialize(raw, connection.msgtype)
            if connection.msgtype == JOINT_STATE:
                if names is None:
                    names = tuple(message.name)
                elif tuple(message.name) != names:
                    raise LogError(f"{source}: {connection.topic}: the joint names change ({names} -> {message.name})")
                joint_time.append(_stamp(message.header))
                joint_rows.append(np.asarray(message.position, dtype=float))
            elif connection.msgtype == IMU:
                o, w = message.orientation, message.angular_velocity
                imu_time.append(_stamp(message.header))
                imu_q.append([o.x, o.y, o.z, o.w])
                imu_w.append([w.x, w.y, w.z])
            else:
                o = message.pose.orientation
                pose_time.append(_stamp(message.header))
                pose_q.append([o.x, o.y, o.z, o.w])
    finally:
        reader.close()
    if not joint_rows or not imu_time:
        raise LogError(f"{source}: the JointState or Imu topic has no message")
    sizes = {row.size for row in joint_rows}
    if sizes != {len(names)}:
        raise LogError(f"{source}: JointState messages of {sorted(sizes)} positions for {len(names)} names")
    time = np.asarray(joint_time)
    position = np.vstack(joint_rows)
    for j, name in enumerate(names):
        _check_stream(f"{source} (JointState)", f"{name} position", time, position[:, j])
    imu_time_a = np.asarray(imu_time)
    imu_quaternion = np.asarray(imu_q, dtype=float)
    for j, axis in enumerate("xyzw"):
        _check_stream(f"{source} (Imu)", f"orientation.{axis}", imu_time_a, imu_quaternion[:, j])
    mocap_time = mocap_quaternion = None
    if pose_time:
        mocap_time, mocap_quaternion = np.asarray(pose_time), np.asarray(pose_q, dtype=float)
        _check_time(f"{source} (PoseStamped)", mocap_time)
    return TrialLog(
        name=path.stem if path.is_file() else path.name,
        joint_names=names,
        joint_time=time,
        joint_position=position,
        imu_time=imu_time_a,
        imu_quaternion=imu_quaternion,
        imu_angular_velocity=np.asarray(imu_w, dtype=float),
        mocap_time=mocap_time,
        mocap_quaternion=mocap_quaternion,
        source=source,
    )


def write_bag(
    path: str | Path,
    log: TrialLog,
    simulated: tuple[np.ndarray, np.ndarray] | None = None,
) -> Path:
    """Write ``log`` (and a replay's ``simulated`` = (time (k,), quaternions (k, 4) x y z w)) as an
    MCAP ROS 2 bag at ``path`` (a folder that must not exist yet: rosbags' layout); returns it."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    store = _typestore()
    header_t = store.types["std_msgs/msg/Header"]
    time_t = store.types["builtin_interfaces/msg/Time"]
    quaternion_t = store.types["geometry_msgs/msg/Quaternion"]
    vector_t = store.types["geometry_msgs/msg/Vector3"]
    point_t = store.types["geometry_msgs/msg/Point"]
    pose_t = store.types["geometry_msgs/msg/Pose"]
    joint_t, imu_t, stamped_t = store.types[JOINT_STATE], store.types[IMU], store.types[POSE]
    path = Path(path)
    zero9 = np.zeros(9)

    def header(t: float, frame: str):
        sec = int(np.floor(t))
        nanosec = int(round((t - sec) * 1e9))
        if nanosec >= 1_000_000_000:
            sec, nanosec = sec + 1, nanosec - 1_000_000_000
        return header_t(stamp=time_t(sec=sec, nanosec=nanosec), frame_id=frame), sec * 1_000_000_000 + nanosec

    def pose(t: float, q: np.ndarray, frame: str):
        h, ns = header(float(t), frame)
        x, y, z, w = (float(v) for v in q)
        body = pose_t(position=point_t(x=0.0, y=0.0, z=0.0), orientation=quaternion_t(x=x, y=y, z=z, w=w))
        return stamped_t(header=h, pose=body), ns

    with Writer(path, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
        joints = writer.add_connection("/joint_states", JOINT_STATE, typestore=store)
        imu = writer.add_connection("/imu", IMU, typestore=store)
        for t, row in zip(log.joint_time, log.joint_position, strict=True):
            h, ns = header(float(t), "")
            message = joint_t(
                header=h, name=list(log.joint_names), position=np.asarray(row, dtype=np.float64),
                velocity=np.zeros(0), effort=np.zeros(0),
            )  # fmt: skip
            writer.write(joints, ns, store.serialize_cdr(message, JOINT_STATE))
        rates = log.imu_angular_velocity if log.imu_angular_velocity is not None else np.zeros((log.imu_time.size, 3))
        for t, q, w in zip(log.imu_time, log.imu_quaternion, rates, strict=True):
            h, ns = header(float(t), "imu")
            message = imu_t(
                header=h,
                orientation=quaternion_t(x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])),
                orientation_covariance=zero9,
                angular_velocity=vector_t(x=float(w[0]), y=float(w[1]), z=float(w[2])),
                angular_velocity_covariance=zero9,
                linear_acceleration=vector_t(x=0.0, y=0.0, z=0.0),
                linear_acceleration_covariance=np.full(9, -1.0),  # ROS: -1 = not measured
            )
            writer.write(imu, ns, store.serialize_cdr(message, IMU))
        if log.mocap_time is not None:
            mocap = writer.add_connection("/mocap/pose", POSE, typestore=store)
            for t, q in zip(log.mocap_time, log.mocap_quaternion, strict=True):
                message, ns = pose(t, q, "world")
                writer.write(mocap, ns, store.serialize_cdr(message, POSE))
        if simulated is not None:
            sim = writer.add_connection("/hydroarm/vehicle_pose", POSE, typestore=store)
            for t, q in zip(*simulated, strict=True):
                message, ns = pose(t, q, "world")
                writer.write(sim, ns, store.serialize_cdr(message, POSE))
    return path


def is_bag(path: str | Path) -> bool:
    """True for an ``.mcap`` / ``.db3`` file or a bag folder (with ``metadata.yaml``)."""
    path = Path(path)
    return path.suffix in (".mcap", ".db3") or (path.is_dir() and (path / "metadata.yaml").is_file())


def trajectory_from_bag(path: str | Path, control_period: float | None = None):
    """The run that ``hydroarm ros2 sim --record`` wrote to the bag at ``path``, as a
    :class:`~hydroarm.sim.runner.Trajectory` (K rows: the states but the last).

    Row k: ``x`` = ``y`` the measured joint state of ``/joint_states`` at t_k (what was on the
    wire: the true state only where the sensor is ideal), ``u`` the torque applied over the step
    from t_k (the ``effort`` of the next state: each state carries the torque of the step that
    ended at its stamp), ``q_ref``, ``v_ref`` from ``/hydroarm/joint_reference`` at t_k; the
    disturbance and its estimate NaN (not on the graph). A stamp sent twice (the simulator's
    re-sends in lockstep) counts once. :class:`LogError` for a bag without the two topics."""
    from hydroarm.sim.runner import Trajectory

    path = Path(path)
    reader = _open_bag(path)
    try:
        topics = {c.topic: c for c in reader.connections if c.msgtype == JOINT_STATE}
        if "/joint_states" not in topics or REFERENCE_TOPIC not in topics:
            listed = ", ".join(f"{c.topic} ({c.msgtype})" for c in reader.connections) or "none"
            raise LogError(
                f"{path}: a recorded run needs /joint_states and {REFERENCE_TOPIC} ({JOINT_STATE}; "
                f"hydroarm ros2 sim --record writes them); topics: {listed}"
            )
        rows: dict[str, dict[int, tuple]] = {"/joint_states": {}, REFERENCE_TOPIC: {}}
        names = None
        for connection, _, raw in reader.messages(connections=[topics["/joint_states"], topics[REFERENCE_TOPIC]]):
            message = reader.deserialize(raw, JOINT_STATE)
            stamp = int(message.header.stamp.sec) * 1_000_000_000 + int(message.header.stamp.nanosec)
            names = names or tuple(message.name)
            if tuple(message.name) != names:
                raise LogError(f"{path}: {connection.topic}: the joint names change ({names} -> {message.name})")
            fields = (message.position, message.velocity, message.effort)
            rows[connection.topic].setdefault(stamp, tuple(np.asarray(f, dtype=float) for f in fields))
    finally:
        reader.close()
    states, reference = rows["/joint_states"], rows[REFERENCE_TOPIC]
    stamps = sorted(stamp for stamp in states if stamp in reference)
    n = len(names or ())
    if len(stamps) < 2 or any(states[s][0].size != n or states[s][1].size != n for s in stamps):
        raise LogError(f"{path}: fewer than two joint states with their reference, or states without {n} values")
    if any(states[s][2].size != n for s in stamps[1:]):
        raise LogError(f"{path}: /joint_states without the {n} efforts of a recorded run")
    t = np.asarray(stamps[:-1], dtype=float) * 1e-9
    x = np.vstack([np.concatenate(states[s][:2]) for s in stamps[:-1]])
    u = np.vstack([states[s][2] for s in stamps[1:]])
    q_ref = np.vstack([reference[s][0] for s in stamps[:-1]])
    v_ref = np.vstack([reference[s][1] if reference[s][1].size == n else np.full(n, np.nan) for s in stamps[:-1]])
    period = float(np.median(np.diff(t))) if control_period is None else control_period
    nan = np.full((t.size, n), np.nan)
    meta = {
        "controller": f"{path.stem if path.is_file() else path.name} (bag)",
        "duration": (stamps[-1] - stamps[0]) * 1e-9,
        "control_period": period, "steps": int(t.size), "diverged": False, "source": str(path),
        "joint_names": list(names),
    }  # fmt: skip
    return Trajectory(
        t=t, x=x, y=x.copy(), u=u, q_ref=q_ref, v_ref=v_ref, disturbance=nan, disturbance_estimate=nan.copy(),
        disturbance_var=nan.copy(), terminal_violation=np.full(t.size, np.nan), status=np.full(t.size, "", dtype=str),
        events=np.full(t.size, "", dtype=str), meta=meta,
    )  # fmt: skip
