"""The ROS 2 nodes (rclpy): parameters in, messages <-> numpy, core calls, results out.

One module per node: :mod:`.geometry_loader`, :mod:`.interference_checker`, :mod:`.trajectory_planner`,
:mod:`.axis_bridge`; their shared parts are in :mod:`edm_planner.ros`, the programs that bring them up and
drive them over DDS (``make demo``, ``make soak``, the crash drill, the bench's service round trips) in
:mod:`.programs`. Each node's ``main`` sets up the process (:func:`edm_planner.ros.prepare_process`: numba's
cache, Fast DDS on loopback) before ``rclpy.init``.
Importing this package does nothing else.
"""
