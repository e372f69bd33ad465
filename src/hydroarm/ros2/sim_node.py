"""``hydroarm ros2 sim``: the simulated arm as a participant of a ROS 2 graph.

The node runs the one closed loop's blocks (:class:`~hydroarm.sim.loop.Loop`: plant, sensor,
drives) with the controller's slot cut at the graph: it publishes what the sensor delivers as
``sensor_msgs/JointState`` on ``/joint_states`` (the sensor's delay, quantisation, noise and
dropout included; ``effort`` the torque the drives applied), the simulated time on ``/clock``
and the arm's URDF on ``/robot_description`` (latched), and takes the joint torques from
``/<controller_name>/commands`` (``std_msgs/Float64MultiArray``, as ros2_control's forward effort
controller takes them, in the arm's joint order) through a :class:`~hydroarm.ros2.gate.CommandGate`.

Clock (``ros2.clock``): ``"wall"`` steps every control period of wall-clock time with the newest
good command; ``"lockstep"`` steps the simulated time one period when a new command arrives (or
after ``command_timeout`` s without one, counted stale), so that a controller node on the other
side runs exactly the in-process loop.
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
    JointState,
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
from hydroarm.sim.loop import Loop

POLL_PERIOD = 0.0005
"""s: in wall-clock time, the commands are taken this often between two steps."""

RESEND_PERIOD = 0.05
"""s: in lockstep, the state the simulator waits on is published again this often."""


@dataclass
class SimResult:
    """A ``ros2 sim`` run: ``t`` (K,) s, the true state ``x`` (K, 2n), the applied torque ``u`` (K, n)
    N m, the reference ``q_ref`` (K, n) rad, the gate's ``counts`` and whether it ``diverged``."""

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    q_ref: np.ndarray
    counts: dict[str, int]
    diverged: bool
    timing: dict[str, float] = field(default_factory=dict)

    def ep(self) -> list[float]:
        """E_p per joint (rad^2): the mean of (q_r - q)^2 over the steps, as the runner's metrics."""
        n = self.u.shape[1]
        return np.mean((self.q_ref - self.x[:, :n]) ** 2, axis=0).tolist()


class SimNode:
    """The simulated fixed-base arm of ``experiment`` (:func:`~hydroarm.sim.experiment.build_experiment`
    with no controller) on the graph of ``ros`` (module docstring)."""

    def __init__(self, experiment, ros: Ros2Config, urdf: str = ""):
        from cyclonedds.pub import DataWriter
        from cyclonedds.sub import DataReader
        from cyclonedds.topic import Topic

        self.experiment, self.ros = experiment, ros
        self.n = experiment.arm.n_joints
        self.names = [str(name) for name in experiment.arm.model.names[1 : self.n + 1]]
        self.period = experiment.control_period
        self.loop = Loop(experiment.plant, self.period)
        self.gate = CommandGate(self.n, ros.command_timeout, ros.on_stale)
        self._arrivals: list[float] = []
        self.resent = 0
        self.overruns = 0
        self._domain, participant = open_domain(ros)
        self._states = DataWriter(participant, Topic(participant, dds_topic("/joint_states"), JointState), sensor_qos())
        self._clock = DataWriter(participant, Topic(participant, dds_topic("/clock"), Clock), sensor_qos())
        self._tf = DataWriter(participant, Topic(participant, dds_topic("/tf"), TFMessage), command_qos())
        self._links = link_frames(experiment.arm)
        self._tf_data = experiment.arm.model.createData()
        description = Topic(participant, dds_topic("/robot_description"), String)
        self._description = DataWriter(participant, description, latched_qos())
        commands = Topic(participant, dds_topic(ros.command_topic), Float64MultiArray)
        self._commands = DataReader(participant, commands, command_qos())
        if urdf:
            self._description.write(String(urdf))
        # the compiled step compiled (or loaded from numba's cache) now, not while a peer waits
        experiment.plant.step(0.0, experiment.x0, np.zeros(self.n), self.period)

    def _take_commands(self) -> int:
        """Offer every command that arrived to the gate; the number accepted (their arrival
        times kept for :func:`loop_timing`)."""
        accepted = 0
        for sample in self._commands.take(N=64):
            if isinstance(sample, Float64MultiArray):
                now = time.monotonic()
                if self.gate.offer(sample.data, now):
                    accepted += 1
                    self._arrivals.append(now)
        return accepted

    def _publish(self, t: float, y: np.ndarray, applied: np.ndarray) -> None:
        stamp = Time.of(t)
        n = self.n
        state = JointState(Header(stamp, ""), self.names, y[:n].tolist(), y[n : 2 * n].tolist(), applied.tolist())
        self._clock.write(Clock(stamp))
        self._states.write(state)
        self._tf.write(self._transforms(stamp, y[:n]))

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

    def _next_command(self, wait: bool, resend=None) -> np.ndarray:
        """The torque for this step: in lockstep, wait for a new good command (up to the timeout),
        calling ``resend()`` every :data:`RESEND_PERIOD` s meanwhile (a best-effort state can be
        lost, or sent before the controller's reader matched: the step must not stall on it)."""
        if wait:
            now = time.monotonic()
            deadline, again = now + self.ros.command_timeout, now + RESEND_PERIOD
            while time.monotonic() < deadline:
                if self._take_commands():
                    return self.gate.torque(time.monotonic())
                if resend is not None and time.monotonic() > again:
                    resend()
                    self.resent += 1
                    again = time.monotonic() + RESEND_PERIOD
                time.sleep(0.0002)
            self.gate.counts["stale"] += 1
            return self.gate.last.copy() if self.ros.on_stale == "hold" else np.zeros(self.n)
        self._take_commands()
        return self.gate.torque(time.monotonic())

    def run(self, duration: float, seed: int = 0, wait_for_subscriber: float = 10.0, progress=None) -> SimResult:
        """Simulate ``duration`` s (module docstring); ``seed`` drives the sensor's noise and
        dropout as the runner's; waits up to ``wait_for_subscriber`` s for a first command reader
        to match before the first step."""
        from hydroarm.sim.runner import DIVERGENCE_SPEED

        steps = int(round(duration / self.period))
        n, lockstep = self.n, self.ros.clock == "lockstep"
        x0 = self.experiment.x0
        y = self.loop.reset(x0, np.random.default_rng(seed), seed)
        rows = {"t": np.arange(steps) * self.period, "x": np.full((steps, 2 * n), np.nan)}
        rows |= {"u": np.full((steps, n), np.nan), "q_ref": np.full((steps, n), np.nan)}
        self._wait_for_peer(wait_for_subscriber)
        applied, used, diverged = np.zeros(n), steps, False
        published = np.full(steps, np.nan)
        start = time.monotonic()
        for k in range(steps):
            t = rows["t"][k]
            self._publish(t, y, applied)
            published[k] = time.monotonic()
            if not lockstep:
                late = time.monotonic() - (start + (k + 1) * self.period)
                if late > self.period:  # an overrun: move on from now, no burst of late steps
                    start += late
                    self.overruns += 1
                self._serve_until(start + (k + 1) * self.period)
            resend = (lambda t=t, y=y, a=applied: self._publish(t, y, a)) if lockstep else None
            step = self.loop.step(t, self._next_command(lockstep, resend))
            applied = step.applied
            rows["x"][k], rows["u"][k] = step.x, applied
            rows["q_ref"][k] = self.experiment.reference.sample(t)[0]
            speeds = np.abs(step.x_next[n : 2 * n])
            if not np.all(np.isfinite(step.x_next)) or np.max(speeds, initial=0.0) > DIVERGENCE_SPEED:
                used, diverged = k + 1, True
                break
            y, _ = self.loop.measure_next()
            if progress is not None:
                progress(k + 1, steps)
        t, x, u, q_ref = (rows[key][:used] for key in ("t", "x", "u", "q_ref"))
        timing = loop_timing(published[:used], np.asarray(self._arrivals), self.period)
        timing |= {"overruns": self.overruns, "resent_states": self.resent}
        return SimResult(t, x, u, q_ref, dict(self.gate.counts), diverged, timing)

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


def link_frames(arm) -> list[tuple[str, str]]:
    """``(parent, child)`` link names of each joint of ``arm``, as its URDF export names them
    (:func:`~hydroarm.model.urdf_export.arm_to_urdf`: ``base_link``, then ``link<i>`` for joint i)."""
    model = arm.model
    return [
        ("base_link" if model.parents[j] == 0 else f"link{model.parents[j]}", f"link{j}")
        for j in range(1, model.njoints)
    ]
