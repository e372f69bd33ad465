"""``hydroarm ros2 sim`` and ``hydroarm ros2 control``: hydroarm on a live ROS 2 graph (the ros2
extra: Cyclone DDS, no ROS installation; docs/ros2.md)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from hydroarm.cli._common import ConfigOption, SetOption, _experiment_config, _fail, app, console
from hydroarm.config import ConfigError

ros2_app = typer.Typer(help="hydroarm on a ROS 2 graph over Cyclone DDS (the ros2 extra; docs/ros2.md).")
app.add_typer(ros2_app, name="ros2")

DomainOption = Annotated[int, typer.Option("--domain-id", help="ROS_DOMAIN_ID, 0 <= x <= 232.")]
InterfaceOption = Annotated[
    str, typer.Option("--interface", help="Network interface to bind; lo (default): this machine only.")
]
ClockOption = Annotated[
    str, typer.Option("--clock", help="wall: the control period in wall-clock time; lockstep: one period per command.")
]
TimeoutOption = Annotated[float, typer.Option("--command-timeout", help="Stale after this long without (s).")]
StaleOption = Annotated[str, typer.Option("--on-stale", help="hold (the last good command) or zero (torque).")]
NameOption = Annotated[
    str, typer.Option("--controller-name", help="The ros2_control controller: commands on /NAME/commands.")
]
ThrusterNameOption = Annotated[
    str,
    typer.Option(
        "--thruster-controller-name", help="On a vehicle: the thrusters' controller: thrusts on /NAME/commands."
    ),
]
DurationOption = Annotated[float, typer.Option("--duration", min=0.0, help="Seconds to run (default: the settings').")]


def _ros2_config(**values):
    try:
        import cyclonedds  # noqa: F401
    except ImportError:
        _fail("hydroarm ros2 needs the ros2 extra (Cyclone DDS): pip install 'hydroarm[ros2]'")
    from hydroarm.config import validate
    from hydroarm.ros2.participant import Ros2Config

    try:
        return validate(Ros2Config, values, "ros2")
    except ConfigError as error:
        _fail(str(error))


def _check_vehicle(ros, experiment) -> None:
    try:
        ros.check_vehicle(experiment.uvms is not None)
    except ValueError as error:
        raise ConfigError(str(error)) from None


def _write(out: Path | None, name: str, data: dict) -> None:
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        (out / name).write_text(json.dumps(data, indent=1) + "\n")


@ros2_app.command()
def sim(
    config_file: ConfigOption = None,
    overrides: SetOption = None,
    duration: DurationOption = 0.0,
    seed: Annotated[int, typer.Option("--seed", min=0, help="Sensor noise and dropout seed.")] = 0,
    domain_id: DomainOption = 0,
    interface: InterfaceOption = "lo",
    clock: ClockOption = "wall",
    command_timeout: TimeoutOption = 0.5,
    on_stale: StaleOption = "hold",
    controller_name: NameOption = "effort_controller",
    thruster_controller_name: ThrusterNameOption = "thruster_controller",
    wait: Annotated[
        float, typer.Option("--wait", min=0.0, max=3600.0, help="Seconds to wait for a command publisher.")
    ] = 10.0,
    out: Annotated[Path | None, typer.Option("--out", help="Folder for ros2_sim.json (E_p, counts).")] = None,
    record: Annotated[
        Path | None, typer.Option("--record", help="Write the node's traffic to this ROS 2 bag (MCAP; a new folder).")
    ] = None,
) -> None:
    """The simulated arm on the graph: /joint_states (through the sensor model), /clock, /tf,
    /robot_description; joint torques from /CONTROLLER_NAME/commands; on a vehicle (vehicle.name)
    also /imu and /odom, thrusts from /THRUSTER_CONTROLLER_NAME/commands. Example:
    hydroarm ros2 sim --set arm=paper --clock lockstep --duration 10"""
    ros = _ros2_config(
        domain_id=domain_id, interface=interface, clock=clock, command_timeout=command_timeout,
        on_stale=on_stale, controller_name=controller_name, thruster_controller_name=thruster_controller_name,
    )  # fmt: skip
    try:
        from hydroarm.model.arm.urdf_export import arm_to_urdf
        from hydroarm.ros2.record import BagRecorder
        from hydroarm.ros2.sim_node import SimNode
        from hydroarm.sim.experiment import build_experiment

        config = _experiment_config(config_file, overrides or [])
        experiment = build_experiment(config, None)
        _check_vehicle(ros, experiment)
        recorder = None if record is None else BagRecorder(record)
        node = SimNode(experiment, ros, urdf=arm_to_urdf(experiment.arm), record=recorder)
    except ConfigError as error:
        _fail(str(error))
    where = f"domain {ros.domain_id} on {ros.interface}"
    on = "" if experiment.uvms is None else f" on {experiment.uvms.vehicle.name}"
    console.print(f"ros2 sim: {experiment.arm.name}{on}, {len(node.names)} joints, {where}")
    try:
        result = node.run(duration or config.duration, seed=seed, wait_for_subscriber=wait)
    finally:
        if recorder is not None:
            recorder.close()
    summary = {"Ep": result.ep(), "steps": len(result.t), "diverged": result.diverged, "counts": result.counts}
    if result.thruster_counts is not None:
        summary["thruster_counts"] = result.thruster_counts
    summary["final_state"] = result.final_state.tolist()
    summary["timing"] = result.timing
    _write(out, "ros2_sim.json", summary)
    console.print(f"E_p per joint (rad^2): {[round(v, 6) for v in summary['Ep']]}; commands {result.counts}")
    if recorder is not None:
        console.print(f"recorded {recorder.messages} messages to {record}")
    if result.diverged:
        raise typer.Exit(1)


@ros2_app.command()
def control(
    controller: Annotated[str, typer.Option("--controller", help="A registered controller (hydroarm controllers).")],
    config_file: ConfigOption = None,
    overrides: SetOption = None,
    duration: DurationOption = 0.0,
    wait: Annotated[float, typer.Option("--wait", min=0.0, help="Seconds to wait for the first joint state.")] = 30.0,
    domain_id: DomainOption = 0,
    interface: InterfaceOption = "lo",
    clock: ClockOption = "wall",
    command_timeout: TimeoutOption = 0.5,
    controller_name: NameOption = "effort_controller",
    thruster_controller_name: ThrusterNameOption = "thruster_controller",
    out: Annotated[Path | None, typer.Option("--out", help="Folder for ros2_control.json (counts).")] = None,
) -> None:
    """A hydroarm controller as a node: /joint_states in, /CONTROLLER_NAME/commands out (on a
    vehicle also /odom in, /THRUSTER_CONTROLLER_NAME/commands out); never a command before a
    state, none after --command-timeout without one. Example:
    hydroarm ros2 control --controller idmpc --set arm=paper --clock lockstep"""
    ros = _ros2_config(
        domain_id=domain_id, interface=interface, clock=clock, command_timeout=command_timeout,
        controller_name=controller_name, thruster_controller_name=thruster_controller_name,
    )  # fmt: skip
    try:
        from hydroarm.ros2.control_node import ControlNode
        from hydroarm.sim.experiment import build_experiment

        config = _experiment_config(config_file, overrides or [])
        experiment = build_experiment(config, controller)
        _check_vehicle(ros, experiment)
        node = ControlNode(experiment, ros)
    except ConfigError as error:
        _fail(str(error))
    counts = node.run(duration or config.duration, wait=wait, log=console.print)
    _write(out, "ros2_control.json", {"controller": node.controller.name, "counts": counts})
    console.print(f"ros2 control: {counts}")
