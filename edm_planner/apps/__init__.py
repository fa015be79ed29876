"""Programs that prepare the machine without ROS; each runs with ``python -m``.

* :mod:`.warmup` -- ``make setup``: every numba kernel compiled into the cache once.

The programs that bring the nodes up and drive them (``make demo``, ``make soak``, the crash drill) import
rclpy, so they live in the ROS shell: :mod:`edm_planner.nodes.programs`. Nothing here imports rclpy or a ROS
message (``.importlinter``).

Entry points: each calls :func:`edm_planner.environment.configure_process` before the core is imported.
"""
