"""``hydroarm ros2 control``: any hydroarm controller as a ROS 2 node for an arm (simulated or real).

It takes ``sensor_msgs/JointState`` from ``/joint_states`` and publishes the controller's joint
torques on ``/<controller_name>/commands`` (``std_msgs/Float64MultiArray``, the form ros2_control's
forward effort controller takes), one command per state received, in the order of the arm's
joints (the state's ``name`` field maps its entries; a state that lacks a joint, has the wrong
length or a non-finite value is dropped and counted). Safe: it never commands before it has
received a state, and when no state arrives for ``command_timeout`` s it stops commanding (and
says so); the controller observes each transition between two consecutive good states, as in the
runner. In lockstep (``ros2.clock = "lockstep"``) the state's stamp is snapped to the control
period's grid, so that two processes on the graph run exactly the in-process loop.

On a vehicle (``vehicle.name`` set: the controller is the whole system's, the arm's controller +
the station keeper) the node also takes ``nav_msgs/Odometry`` from ``/odom`` (the base's pose in
the world frame, its body twist: what ``hydroarm ros2 sim`` publishes,
:mod:`hydroarm.ros2.vehicle_topics`), answers each stamp once both its joint state and its
odometry arrived, and publishes the thrusts (N, the vehicle file's thruster order) on
``/<thruster_controller_name>/commands`` beside the arm's torques. The station keeper reads the
pose and twist only (the thrusters' delivered forces, the rest of the plant's state, are not on
the graph and not used).
"""

from __future__ import annotations

import time

import numpy as np

from hydroarm.ros2.messages import Float64MultiArray, JointState, Odometry, dds_topic
from hydroarm.ros2.participant import Ros2Config, command_qos, open_domain, sensor_qos


class ControlNode:
    """The controller of ``experiment`` (:func:`~hydroarm.sim.experiment.build_experiment` with a
    controller) on the graph of ``ros`` (module docstring)."""

    def __init__(self, experiment, ros: Ros2Config):
        from cyclonedds.pub import DataWriter
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        self.experiment, self.ros = experiment, ros
        self.controller = experiment.controller
        self.n = experiment.arm.n_joints
        self.names = [str(name) for name in experiment.arm.model.names[1 : self.n + 1]]
        self.period = experiment.control_period
        self.counts = {"states": 0, "commands": 0, "dropped_states": 0, "repeated_states": 0, "timeouts": 0}
        self.vehicle = experiment.uvms is not None
        self._domain, participant = open_domain(ros)
        self._states = DataReader(participant, Topic(participant, dds_topic("/joint_states"), JointState), sensor_qos())
        topic = Topic(participant, dds_topic(ros.command_topic), Float64MultiArray)
        self._commands = DataWriter(participant, topic, command_qos())
        self._odometry = self._thrusts = None
        self._waiting: dict[int, list] = {}  # a vehicle's stamp (ns) -> [joint state, odometry] until both came
        if self.vehicle:
            self.counts["dropped_odometry"] = 0
            odometry = Topic(participant, dds_topic("/odom"), Odometry)
            self._odometry = DataReader(participant, odometry, sensor_qos())
            thrusts = Topic(participant, dds_topic(ros.thruster_topic), Float64MultiArray)
            self._thrusts = DataWriter(participant, thrusts, command_qos())
        self._last: tuple[float, np.ndarray, np.ndarray] | None = None
        self._answered = -np.inf  # the stamp of the last state answered (s)
        # the controller's compiled code compiled (or loaded from numba's cache) now, not while the arm waits
        self.controller.compute(0.0, experiment.x0, experiment.reference)
        self.controller.reset()

    def measurement(self, state: JointState) -> np.ndarray | None:
        """The state's [q, v] (2n,) in the arm's joint order, or None (dropped) when a joint is
        missing, the lengths disagree or a value is not finite."""
        names = list(state.name)
        if len(state.position) != len(names) or len(state.velocity) != len(names):
            return None
        index = {name: i for i, name in enumerate(names)}
        if any(name not in index for name in self.names):
            return None
        order = [index[name] for name in self.names]
        y = np.concatenate([np.asarray(state.position)[order], np.asarray(state.velocity)[order]]).astype(float)
        return y if np.all(np.isfinite(y)) else None

    def vehicle_state(self, y_arm: np.ndarray, odometry: Odometry) -> np.ndarray | None:
        """The floating plant's state ``[pose (7), q_arm, twist (6), v_arm, thrust]`` from the arm's
        [q, v] and the odometry (thrust: zeros, not on the graph and not read), or None (dropped)
        when a value is not finite or the quaternion is not a unit one (to 1e-6)."""
        pose, twist = odometry.pose.pose, odometry.twist.twist
        o = pose.orientation
        base = np.array([pose.position.x, pose.position.y, pose.position.z, o.x, o.y, o.z, o.w], dtype=float)
        velocity = [twist.linear.x, twist.linear.y, twist.linear.z, twist.angular.x, twist.angular.y, twist.angular.z]
        velocity = np.asarray(velocity, dtype=float)
        if not (np.all(np.isfinite(base)) and np.all(np.isfinite(velocity))):
            return None
        if abs(np.linalg.norm(base[3:]) - 1.0) > 1e-6:
            return None
        plant, n = self.experiment.plant, self.n
        return np.concatenate([base, y_arm[:n], velocity, y_arm[n:], np.zeros(plant.state_size - plant.nq - plant.nv)])

    def handle_vehicle(self, state: JointState, odometry: Odometry) -> np.ndarray | None:
        """A vehicle's joint state and odometry of one stamp in, one command out, or None."""
        self.counts["states"] += 1
        y_arm = self.measurement(state)
        y = None if y_arm is None else self.vehicle_state(y_arm, odometry)
        if y is None:
            self.counts["dropped_states" if y_arm is None else "dropped_odometry"] += 1
            self._last = None
            return None
        return self._answer(state.header.stamp.seconds(), y)

    def handle(self, state: JointState) -> np.ndarray | None:
        """One state in, one command out (published; also returned), or None when dropped."""
        self.counts["states"] += 1
        y = self.measurement(state)
        if y is None:
            self.counts["dropped_states"] += 1
            self._last = None  # no transition across a dropped state
            return None
        return self._answer(state.header.stamp.seconds(), y)

    def _answer(self, t: float, y: np.ndarray) -> np.ndarray | None:
        """The controller's command for the measured ``y`` at the stamp ``t`` (s), published."""
        if self.ros.clock == "lockstep":
            t = round(t / self.period) * self.period
        if t <= self._answered:
            self.counts["repeated_states"] += 1  # answered already (the simulator published it again)
            return None
        if self._last is not None:
            self.controller.observe(*self._last, y)
        tau = np.asarray(self.controller.compute(t, y, self.experiment.reference).tau, dtype=float)
        if tau.shape != (self.experiment.plant.n_inputs,) or not np.all(np.isfinite(tau)):
            self._last = None
            return None  # the controller's own fault: no command rather than a bad one
        if self._thrusts is not None:
            self._thrusts.write(Float64MultiArray(data=tau[self.n :].tolist()))
        self._commands.write(Float64MultiArray(data=tau[: self.n].tolist()))
        self.counts["commands"] += 1
        self._last, self._answered = (t, y, tau), t
        return tau

    def run(self, duration: float, wait: float = 30.0, log=print) -> dict[str, int]:
        """Serve for ``duration`` s of wall-clock time after the first state (or until no state came
        for ``command_timeout`` s after one did); the counts. Never commands before a state: waits
        up to ``wait`` s for the first one."""
        self.controller.reset()
        self._last, self._answered = None, -np.inf
        first, last_state, started = None, None, time.monotonic()
        while True:
            now = time.monotonic()
            if first is None and now - started > wait:
                log(f"no joint state on /joint_states in {wait:g} s: never commanded")
                return self.counts
            samples = [s for s in self._states.take(N=64) if isinstance(s, JointState)]
            if self.vehicle:
                samples += self._take_vehicle(samples)
            else:
                for state in samples:
                    self.handle(state)
            if samples:
                first, last_state = first or now, now
            elif last_state is not None and now - last_state > self.ros.command_timeout:
                self.counts["timeouts"] += 1
                log(f"no joint state for {self.ros.command_timeout:g} s: stopped commanding")
                return self.counts
            if first is not None and now - first > duration:
                return self.counts
            if not samples:
                time.sleep(0.0002)

    def _take_vehicle(self, states: list[JointState]) -> list:
        """Pair the joint states with the odometry of the same stamp and answer each pair; the
        odometry samples that arrived (for the timeout)."""
        odometry = [s for s in self._odometry.take(N=64) if isinstance(s, Odometry)]
        for slot, sample in [(0, s) for s in states] + [(1, s) for s in odometry]:
            stamp = sample.header.stamp
            key = stamp.sec * 1_000_000_000 + stamp.nanosec
            pair = self._waiting.setdefault(key, [None, None])
            pair[slot] = sample
            if pair[0] is not None and pair[1] is not None:
                del self._waiting[key]
                self.handle_vehicle(*pair)
        for key in sorted(self._waiting)[:-8]:  # an unpaired stamp is not kept for long
            del self._waiting[key]
        return odometry
