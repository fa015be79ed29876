"""Programs that bring the nodes up and drive them over DDS (rclpy); each runs with ``python -m``.

* :mod:`.demo` -- ``make demo``: the four nodes, one channel of the default blisk planned, a summary, plots
  (its steps in :mod:`.demo_steps`; :mod:`.bringup` starts the nodes as processes);
* :mod:`.soak` -- ``make soak``: thousands of calls from two clients, memory and latency;
* :mod:`.crash_drill` -- a node killed mid-call and what the others do (Fast DDS transports);
* :mod:`.service_bench` -- the service round trips of ``make bench`` (nodes in its process, JSON out), which
  :mod:`edm_planner.bench.service` runs as a child process.

They are part of the ROS shell (the nodes' layer), since they import rclpy and the messages: the layers above,
:mod:`edm_planner.apps` and :mod:`edm_planner.bench`, run them as processes and import no ROS
(``.importlinter``). Entry points: each calls :func:`edm_planner.environment.configure_process` before the core
is imported. Importing this package does nothing else.
"""
