"""hydroarm on a live ROS 2 graph over Cyclone DDS, with no ROS installation (the ros2 extra):
the messages on the wire (:mod:`~hydroarm.ros2.messages`), the participant's settings and QoS
(:mod:`~hydroarm.ros2.participant`), the checks on what arrives (:mod:`~hydroarm.ros2.gate`), the
simulated arm (:mod:`~hydroarm.ros2.sim_node`) and a controller node
(:mod:`~hydroarm.ros2.control_node`). docs/ros2.md says how to connect a ROS 2 graph."""
