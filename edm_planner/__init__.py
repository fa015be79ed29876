"""edm_planner: electrode path planning for five-axis EDM of shrouded blisks.

The sub-packages ``geometry`` (and, later, ``interference``, ``planning``,
``machine``) are plain numpy/scipy/trimesh code without rclpy; ``nodes`` holds
the thin ROS 2 adapters.
"""

__version__ = "0.1.0"
