"""``hydroarm ros2 sim --record BAG``: the node's traffic on the graph into a ROS 2 bag (rosbags,
MCAP, ROS 2 type names) that ``hydroarm compare`` (the arm) and ``hydroarm replay`` (a vehicle)
read back.

The simulator records, rather than a separate subscriber: it holds every message it publishes
and every command it takes, so the bag has all of them (a recorder on the graph would take the
best-effort joint states as the graph delivers them: some can be lost on a loaded machine), and
each is written as the bytes that went on the wire (Cyclone DDS's CDR, equal to rosbags'
serialisation: ``tests/test_ros2.py``). Times: the simulated time of the step the message belongs
to (ns), for the states their stamp, for a command the state it answered. A state the simulator
publishes again in lockstep (the same messages, while it waits for a command) is recorded once.
"""

from __future__ import annotations

from pathlib import Path

from hydroarm.config import ConfigError
from hydroarm.ros2.messages import ROS_NAMES


class BagRecorder:
    """A ROS 2 bag being written at ``path`` (a folder that must not exist: rosbags' layout);
    :meth:`write` adds a message, :meth:`close` finishes the bag."""

    def __init__(self, path: str | Path):
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.typesys import Stores, get_typestore

        self.path = Path(path)
        if self.path.exists():
            raise ConfigError(f"--record {self.path}: exists; give a new folder for the bag")
        if self.path.suffix == ".bag":  # readers (rosbags' AnyReader, ros2 bag) take a .bag for a ROS 1 bag file
            raise ConfigError(f"--record {self.path}: a ROS 2 bag is a folder; name it without .bag (e.g. run1)")
        self._store = get_typestore(Stores.ROS2_HUMBLE)
        self._writer = Writer(self.path, version=8, storage_plugin=StoragePlugin.MCAP)
        self._writer.open()
        self._connections: dict[str, object] = {}
        self.messages = 0

    def write(self, topic: str, message, t: float) -> None:
        """``message`` (a :mod:`hydroarm.ros2.messages` type) on ``topic`` at simulated time ``t`` (s)."""
        connection = self._connections.get(topic)
        if connection is None:
            connection = self._writer.add_connection(topic, ROS_NAMES[type(message)], typestore=self._store)
            self._connections[topic] = connection
        self._writer.write(connection, max(0, round(t * 1e9)), bytes(message.serialize()))
        self.messages += 1

    def close(self) -> None:
        self._writer.close()
