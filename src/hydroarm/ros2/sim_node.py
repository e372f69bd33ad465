"""``hydroarm ros2 sim``: the simulated arm as a participant of a ROS 2 graph.

The node runs the one closed loop's blocks (:class:`~hydroarm.sim.loop.Loop`: plant, sensor,
drives) with the controller's slot cut at the graph: it publishes what the sensor delivers as
``sensor_msgs/JointState`` on ``/joint_states`` (the sensor's delay, quantisation, noise and
dropout included; ``effort`` the torque the drives applied), the simulated time on ``/clock``
and the arm's URDF on ``/robot_description`` (latched), and takes the joint torques from
``/<controller_name>/commands`` (``std_msgs/Float64MultiArray``, as ros2_control's forward effort
controller takes them, in the arm's joint order) through a :class:`~hydroarm.ros2.gate.CommandGate`.

The arm's reference is on ``/hydroarm/joint_reference`` (``sensor_msgs/JointState``: the task's
joint positions and velocities at the stamp), so that a recorded run's E_p can be read back
(``hydroarm compare BAG``). After the last step the node publishes the state it ended at.

On a vehicle (``vehicle.name`` set: the experiment's plant is the floating system, stepped by the
same :class:`~hydroarm.sim.loop.Loop`), the joint states are the mounted arm's and the node also
publishes ``/imu``, ``/odom`` and the vehicle's frames on ``/tf``, and takes the thrusts from
``/<thruster_controller_name>/commands`` through a second gate
(:mod:`hydroarm.ros2.vehicle_topics`).

Clock (``ros2.clock``): ``"wall"`` steps every control period of wall-clock time with the newest
good command; ``"lockstep"`` steps the simulated time one period when a new command arrives (on
a vehicle: a new arm command and a new thrust command; or after ``command_timeout`` s without,
counted stale), so that a controller node on the other side runs exactly the in-process loop.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from hydroarm.ros2.gate import CommandGate
from hydroarm.ros2.messages import (
    Clock,
    Float64MultiArray,
    Header,
    Imu,
    JointState,
    Odometry,
    Quaternion,
    String,
    TFMessage,
    Time,
    Transform,
    TransformStamped,
    Vector3,
    dds_topic,
)
from hydroarm.ros2.participant import Ros2Config, command_qos, latched_qos, open_domain, sensor_qos
from hydroarm.ros2.vehicle_topics import ARM_PREFIX, VehicleState
from hydroarm.sim.loop import Loop

POLL_PERIOD = 0.0005
"""s: in wall-clock time, the commands are taken this often between two steps."""

RESEND_PERIOD = 0.05
"""s: in lockstep, the state the simulator waits on is published again this often."""


@dataclass
class SimResult:
    """A ``ros2 sim`` run: ``t`` (K,) s, the joints' true state ``x`` (K, 2n), the applied torque
    ``u`` (K, n) N m, the reference ``q_ref`` (K, n) rad, the arm's gate's ``counts`` (on a vehicle
    also the thrusters' gate's, ``thruster_counts``), whether it ``diverged``, and the plant's
    whole true state at the end ``final_state`` (``plant.state_size``,)."""

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    q_ref: np.ndarray
    counts: dict[str, int]
    diverged: bool
    timing: dict[str, float] = field(default_factory=dict)
    thruster_counts: dict[str, int] | None = None
    final_state: np.ndarray | None = None

    def ep(self) -> list[float]:
        """E_p per joint (rad^2): the mean of (q_r - q)^2 over the steps, as the runner's metrics."""
        n = self.u.shape[1]
        return np.mean((self.q_ref - self.x[:, :n]) ** 2, axis=0).tolist()


class SimNode:
    """The simulated arm of ``experiment`` (:func:`~hydroarm.sim.experiment.build_experiment` with
    no controller; fixed-base or on its vehicle) on the graph of ``ros`` (module docstring);
    ``record``: a :class:`~hydroarm.ros2.record.BagRecorder` that gets every message."""

    def __init__(self, experiment, ros: Ros2Config, urdf: str = "", record=None):
        from cyclonedds.pub import DataWriter
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        self.experiment, self.ros, self.record = experiment, ros, record
        self.plant = experiment.plant
        self.n = self.plant.n
        self.names = [str(name) for name in experiment.arm.model.names[1 : self.n + 1]]
        self.period = experiment.control_period
        self.loop = Loop(self.plant, self.period)
        self.gate = CommandGate(self.n, ros.command_timeout, ros.on_stale)
        self.vehicle = None if experiment.uvms is None else VehicleState(self.plant, experiment.arm)
        thrusters = self.plant.n_inputs - self.n
        self.thruster_gate = None if self.vehicle is None else CommandGate(thrusters, ros.command_timeout, ros.on_stale)
        self._arrivals: list[float] = []
        self._sim_time = 0.0
        self._resending = False
        self.resent = 0
        self.overruns = 0
        self._domain, participant = open_domain(ros)

        def writer(topic: str, kind, qos):
            return DataWriter(participant, Topic(participant, dds_topic(topic), kind), qos)

        self._writers = {"/clock": writer("/clock", Clock, sensor_qos())}
        self._writers["/joint_states"] = writer("/joint_states", JointState, sensor_qos())
        self._writers["/hydroarm/joint_reference"] = writer("/hydroarm/joint_reference", JointState, sensor_qos())
        self._writers["/tf"] = writer("/tf", TFMessage, command_qos())
        if self.vehicle is not None:
            self._writers["/imu"] = writer("/imu", Imu, sensor_qos())
            self._writers["/odom"] = writer("/odom", Odometry, sensor_qos())
        self._links = link_frames(experiment.arm, ARM_PREFIX if self.vehicle is not None else "")
        self._tf_data = experiment.arm.model.createData()
        self._readers = {}
        for topic in (ros.command_topic, *([ros.thruster_topic] if self.vehicle is not None else [])):
            commands = Topic(participant, dds_topic(topic), Float64MultiArray)
            self._readers[topic] = DataReader(participant, commands, command_qos())
        self._commands = self._readers[ros.command_topic]
        description = writer("/robot_description", String, latched_qos())
        if urdf:
            description.write(String(urdf))
            if record is not None:
                record.write("/robot_description", String(urdf), 0.0)
        self._description = description
        # the compiled step compiled (or loaded from numba's cache) now, not while a peer waits
        self.plant.step(0.0, experiment.x0, np.zeros(self.plant.n_inputs), self.period)
        if self.vehicle is not None:
            self.vehicle.specific_force(0.0, experiment.x0, np.zeros(self.plant.n_inputs))

    def _take_commands(self) -> int:
        """Offer every command that arrived to its gate; the number of arm commands accepted
        (their arrival times kept for :func:`loop_timing`)."""
        accepted = 0
        for topic, reader in self._readers.items():
            gate = self.gate if topic == self.ros.command_topic else self.thruster_gate
            for sample in reader.take(N=64):
                if isinstance(sample, Float64MultiArray):
                    now = time.monotonic()
                    if self.record is not None:
                        self.record.write(topic, sample, self._sim_time)
                    if gate.offer(sample.data, now) and gate is self.gate:
                        accepted += 1
                        self._arrivals.append(now)
        return accepted

    def _write(self, topic: str, message, t: float) -> None:
        self._writers[topic].write(message)
        if self.record is not None and not self._resending:
            self.record.write(topic, message, t)

    def _publish(self, t: float, y: np.ndarray, applied: np.ndarray, resend: bool = False) -> None:
        """The state ``y`` at ``t`` (s) on the graph; ``applied``: the plant's input held over the
        step that ended at ``t`` (its first n entries: the joints' torques, N m); ``resend``: the
        same messages again (lockstep), recorded once."""
        self._resending = resend
        stamp = Time.of(t)
        n = self.n
        joints = self.plant.joint_state(y)
        efforts = applied[:n].tolist()
        state = JointState(Header(stamp, ""), self.names, joints[:n].tolist(), joints[n : 2 * n].tolist(), efforts)
        q_ref, v_ref, _ = self.experiment.reference.sample(t)
        reference = JointState(Header(stamp, ""), self.names, np.asarray(q_ref).tolist(), np.asarray(v_ref).tolist())
        self._write("/clock", Clock(stamp), t)
        self._write("/joint_states", state, t)
        self._write("/hydroarm/joint_reference", reference, t)
        tf = self._transforms(stamp, joints[:n])
        if self.vehicle is not None:
            tf.transforms[:0] = self.vehicle.transforms(stamp, y)
            self._write("/imu", self.vehicle.imu(stamp, t, y, applied), t)
            self._write("/odom", self.vehicle.odometry(stamp, y), t)
        self._write("/tf", tf, t)

    def _transforms(self, stamp: Time, q: np.ndarray) -> TFMessage:
        """Each link's frame in its parent's at the measured ``q`` (rad), as robot_state_publisher
        gives them from ``/joint_states`` and the URDF of ``/robot_description``."""
        import pinocchio as pin

        model, data = self.experiment.arm.model, self._tf_data
        pin.forwardKinematics(model, data, q)
        transforms = []
        for joint, (parent, child) in enumerate(self._links, start=1):
            placement = data.liMi[joint]
            x, y, z, w = pin.Quaternion(placement.rotation).coeffs()
            transform = Transform(
                Vector3(*placement.translation.tolist()), Quaternion(float(x), float(y), float(z), float(w))
            )
            transforms.append(TransformStamped(Header(stamp, parent), child, transform))
        return TFMessage(transforms)

    def _gates(self) -> list[CommandGate]:
        return [self.gate] if self.thruster_gate is None else [self.gate, self.thruster_gate]

    def _command(self, now: float) -> np.ndarray:
        """The plant's input at ``now``: the joints' torques, then (on a vehicle) the thrusts."""
        return np.concatenate([gate.torque(now) for gate in self._gates()])

    def _next_command(self, wait: bool, resend=None) -> np.ndarray:
        """The input for this step: in lockstep, wait for a new good command on every gate (up to
        the timeout), calling ``resend()`` every :data:`RESEND_PERIOD` s meanwhile (a best-effort
        state can be lost, or sent before the controller's reader matched: the step must not
        stall on it)."""
        if wait:
            gates = self._gates()
            before = [gate.counts["accepted"] for gate in gates]
            now = time.monotonic()
            deadline, again = now + self.ros.command_timeout, now + RESEND_PERIOD
            while time.monotonic() < deadline:
                self._take_commands()
                if all(gate.counts["accepted"] > b for gate, b in zip(gates, before)):
                    return self._command(time.monotonic())
                if resend is not None and time.monotonic() > again:
                    resend()
                    self.resent += 1
                    again = time.monotonic() + RESEND_PERIOD
                time.sleep(0.0002)
            parts = []
            for gate, b in zip(gates, before):
                if gate.counts["accepted"] > b:
                    parts.append(gate.last.copy())
                    continue
                gate.counts["stale"] += 1
                parts.append(gate.last.copy() if self.ros.on_stale == "hold" else np.zeros(gate.n))
            return np.concatenate(parts)
        self._take_commands()
        return self._command(time.monotonic())

    def run(self, duration: float, seed: int = 0, wait_for_subscriber: float = 10.0, progress=None) -> SimResult:
        """Simulate ``duration`` s (module docstring); ``seed`` drives the sensor's noise and
        dropout as the runner's; waits up to ``wait_for_subscriber`` s for a first command reader
        to match before the first step."""
        from hydroarm.sim.runner import DIVERGENCE_SPEED

        steps = int(round(duration / self.period))
        n, lockstep, plant = self.n, self.ros.clock == "lockstep", self.plant
        x0 = self.experiment.x0
        y = self.loop.reset(x0, np.random.default_rng(seed), seed)
        rows = {"t": np.arange(steps) * self.period, "x": np.full((steps, 2 * n), np.nan)}
        rows |= {"u": np.full((steps, n), np.nan), "q_ref": np.full((steps, n), np.nan)}
        self._wait_for_peer(wait_for_subscriber)
        applied, used, diverged = np.zeros(plant.n_inputs), steps, False
        published = np.full(steps, np.nan)
        start = time.monotonic()
        final = np.asarray(x0, dtype=float)
        for k in range(steps):
            t = rows["t"][k]
            self._sim_time = t
            self._publish(t, y, applied)
            published[k] = time.monotonic()
            if not lockstep:
                late = time.monotonic() - (start + (k + 1) * self.period)
                if late > self.period:  # an overrun: move on from now, no burst of late steps
                    start += late
                    self.overruns += 1
                self._serve_until(start + (k + 1) * self.period)
            resend = (lambda t=t, y=y, a=applied: self._publish(t, y, a, resend=True)) if lockstep else None
            step = self.loop.step(t, self._next_command(lockstep, resend))
            applied, final = step.applied, step.x_next
            rows["x"][k], rows["u"][k] = plant.joint_state(step.x), applied[:n]
            rows["q_ref"][k] = self.experiment.reference.sample(t)[0]
            speeds = np.abs(plant.joint_state(step.x_next)[n : 2 * n])
            if not np.all(np.isfinite(step.x_next)) or np.max(speeds, initial=0.0) > DIVERGENCE_SPEED:
                used, diverged = k + 1, True
                break
            y, _ = self.loop.measure_next()
            if progress is not None:
                progress(k + 1, steps)
        if not diverged and steps:  # the state the run ended at (its efforts: the last step's)
            self._sim_time = steps * self.period
            self._publish(self._sim_time, y, applied)
        t, x, u, q_ref = (rows[key][:used] for key in ("t", "x", "u", "q_ref"))
        timing = loop_timing(published[:used], np.asarray(self._arrivals), self.period)
        timing |= {"overruns": self.overruns, "resent_states": self.resent}
        thrusters = None if self.thruster_gate is None else dict(self.thruster_gate.counts)
        return SimResult(t, x, u, q_ref, dict(self.gate.counts), diverged, timing, thrusters, np.asarray(final))

    def _serve_until(self, tick: float) -> None:
        """Take the commands as they arrive (their arrival times to within :data:`POLL_PERIOD`)
        until the monotonic time ``tick`` (s)."""
        while (left := tick - time.monotonic()) > 0.0:
            self._take_commands()
            time.sleep(min(POLL_PERIOD, left))

    def _wait_for_peer(self, seconds: float) -> None:
        """Until a command writer matched the node's reader, or ``seconds`` passed."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline and not self._commands.get_matched_publications():
            time.sleep(0.01)


def loop_timing(published: np.ndarray, arrivals: np.ndarray, period: float) -> dict[str, float]:
    """The loop's timing over the graph, in ms: the period's jitter (the spacing of the states'
    publications minus the period T, s) and the command latency (from a state's publication to the
    first command that arrived after it and before the next state: the controller answers each
    state with one command), each as median, p99 and max of the absolute values."""

    def stats(name: str, values: np.ndarray) -> dict[str, float]:
        values = np.abs(values[np.isfinite(values)]) * 1e3
        if values.size == 0:
            return {}
        return {f"{name}_median_ms": float(np.median(values)), f"{name}_p99_ms": float(np.percentile(values, 99)),
                f"{name}_max_ms": float(np.max(values)), f"{name}_samples": int(values.size)}  # fmt: skip

    jitter = np.diff(published) - period
    latency = np.full(published.size, np.nan)
    ends = np.append(published[1:], np.inf)
    for k, (begin, end) in enumerate(zip(published, ends)):
        later = arrivals[(arrivals > begin) & (arrivals <= end)]
        if later.size:
            latency[k] = later[0] - begin
    return stats("jitter", jitter) | stats("latency", latency)


def link_frames(arm, prefix: str = "") -> list[tuple[str, str]]:
    """``(parent, child)`` link names of each joint of ``arm``, as its URDF export names them
    (:func:`~hydroarm.model.arm.urdf_export.arm_to_urdf`: ``base_link``, then ``link<i>`` for joint i),
    each with ``prefix`` in front (robot_state_publisher's ``frame_prefix``)."""
    model = arm.model
    return [
        (prefix + ("base_link" if model.parents[j] == 0 else f"link{model.parents[j]}"), f"{prefix}link{j}")
        for j in range(1, model.njoints)
    ]
