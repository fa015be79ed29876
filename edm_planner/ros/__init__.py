"""The ROS 2 shell's shared parts (rclpy): what every node and every program that drives the nodes uses.

* :mod:`.dds` -- Fast DDS on loopback UDP instead of shared memory where LOCALHOST discovery is asked for
  (:func:`.dds.use_loopback_udp`, called by every entry point before ``rclpy.init``);
* :mod:`.runtime` -- spinning a node with a deadline-aware executor (``spin_node``), turning every exception
  of a service callback into an error code and a message (``answer``), the plan store and machine file
  parameters;
* :mod:`.conversions` -- messages <-> numpy and the core's types, in one place;
* :mod:`.action_client` -- an action client that closes rclpy's goal/result race;
* :mod:`.shared` -- the latched QoS and the config directory, which the nodes and the programs share;
* :mod:`.received` -- the geometries a node received on the latched topic, and the bounded wait for one on its way;
* :mod:`.startup` -- a process's set-up before ``rclpy.init``.

The nodes themselves are in :mod:`edm_planner.nodes`, the programs that drive them in
:mod:`edm_planner.nodes.programs`.
Importing this package does nothing else.
"""
