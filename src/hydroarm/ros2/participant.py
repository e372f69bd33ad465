"""Joining a ROS 2 graph over Cyclone DDS: the settings, the participant's configuration and the
QoS of ROS 2's conventions.

Safe by default: a participant talks on this machine only (Cyclone DDS bound to the loopback
interface, multicast off, its peers found by unicast on 127.0.0.1: ROS 2's
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``), on an explicit domain id. A node that commands
torques on a real arm reaches another machine only when ``ros2.interface`` names that machine's
network interface (and then with multicast discovery, as ROS 2 defaults to).

QoS, as ROS 2's ``rclcpp`` presets:

* :func:`sensor_qos` (``SensorDataQoS``): best effort, volatile, keep last 5: a late joint state
  is useless, a new one replaces it;
* :func:`command_qos` (the default profile): reliable, volatile, keep last 10: a command is not
  dropped on the way;
* :func:`latched_qos` (``/robot_description``, ``/tf_static``): reliable, transient local, keep
  last 1: a subscriber that joins later still gets it.
"""

from __future__ import annotations

from typing import Literal

import pydantic
from cyclonedds.core import Qos as _Qos
from cyclonedds.qos import Policy

from hydroarm.config import FrozenModel

LOOPBACK = "lo"


class Ros2Config(FrozenModel):
    """Where and how a hydroarm node joins the ROS 2 graph (section ``ros2``)."""

    domain_id: int = pydantic.Field(0, ge=0, le=232, description="the ROS 2 domain id (ROS_DOMAIN_ID) (-)")
    interface: str = pydantic.Field(
        LOOPBACK,
        min_length=1,
        max_length=64,
        pattern=r"^[A-Za-z0-9_.:-]+$",
        description="the network interface Cyclone DDS binds to; lo (default): this machine only",
    )
    clock: Literal["wall", "lockstep"] = pydantic.Field(
        "wall",
        description="wall: the node steps at its control period in wall-clock time; lockstep: simulated "
        "time on /clock, one period per command",
    )
    command_timeout: float = pydantic.Field(
        0.5, gt=0.0, le=60.0, description="a missing command or state older than this is stale (s)"
    )
    on_stale: Literal["hold", "zero"] = pydantic.Field(
        "hold", description="the drives on a stale or missing command: hold the last good one, or zero torque"
    )
    controller_name: str = pydantic.Field(
        "effort_controller",
        min_length=1,
        max_length=64,
        pattern=r"^[A-Za-z][A-Za-z0-9_]*$",
        description="the ros2_control forward controller's name: commands on /<controller_name>/commands",
    )
    thruster_controller_name: str = pydantic.Field(
        "thruster_controller",
        min_length=1,
        max_length=64,
        pattern=r"^[A-Za-z][A-Za-z0-9_]*$",
        description="on a vehicle: the thrusters' forward controller: thrusts (N) on /<name>/commands",
    )

    @pydantic.model_validator(mode="after")
    def _two_topics(self) -> Ros2Config:
        if self.thruster_controller_name == self.controller_name:
            raise ValueError(
                f"thruster_controller_name = {self.thruster_controller_name!r}: the arm's controller has this "
                "name; give the thrusters' controller another one"
            )
        return self

    def check_vehicle(self, on_vehicle: bool) -> None:
        """Raise ValueError when ``thruster_controller_name`` was set away from its default for a
        fixed-base arm (no thrusters: the setting would be ignored)."""
        default = type(self).model_fields["thruster_controller_name"].default
        if not on_vehicle and self.thruster_controller_name != default:
            raise ValueError(
                f"ros2.thruster_controller_name = {self.thruster_controller_name!r}: a fixed-base arm has no "
                "thrusters; set vehicle.name, or leave it at its default"
            )

    @property
    def local_only(self) -> bool:
        return self.interface == LOOPBACK

    @property
    def command_topic(self) -> str:
        return f"/{self.controller_name}/commands"

    @property
    def thruster_topic(self) -> str:
        return f"/{self.thruster_controller_name}/commands"


def cyclone_xml(config: Ros2Config) -> str:
    """Cyclone DDS's configuration for ``config``: the interface, and on loopback multicast off
    with 127.0.0.1 as the unicast peer (participant indices auto, up to 32 on the machine)."""
    if config.local_only:
        discovery = (
            "<Discovery><ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>32</MaxAutoParticipantIndex>"
            '<Peers><Peer address="127.0.0.1"/></Peers></Discovery>'
        )
        multicast = "<AllowMulticast>false</AllowMulticast>"
    else:
        discovery, multicast = "", ""
    return (
        '<CycloneDDS><Domain id="any"><General><Interfaces>'
        f'<NetworkInterface name="{config.interface}"/></Interfaces>{multicast}</General>'
        f"{discovery}</Domain></CycloneDDS>"
    )


def open_domain(config: Ros2Config):
    """``(domain, participant)``: the configured Cyclone DDS domain and a participant in it (keep
    the domain alive as long as the participant)."""
    from cyclonedds.domain import Domain, DomainParticipant

    domain = Domain(config.domain_id, config=cyclone_xml(config))
    return domain, DomainParticipant(config.domain_id)


def sensor_qos() -> _Qos:
    return _Qos(Policy.Reliability.BestEffort, Policy.Durability.Volatile, Policy.History.KeepLast(5))


def command_qos() -> _Qos:
    return _Qos(Policy.Reliability.Reliable(0), Policy.Durability.Volatile, Policy.History.KeepLast(10))


def latched_qos() -> _Qos:
    return _Qos(Policy.Reliability.Reliable(0), Policy.Durability.TransientLocal, Policy.History.KeepLast(1))
