"""The machine tool: five-axis kinematics, the machine file (axes, limits, process regimes, NC dialect), toppra
time parameterisation, joint trajectories, the NC post-processor and CSV. No rclpy.

Formerly ``edm_planner.machine`` (renamed in issue 27: ``machine`` and ``machining`` were nearly the same word;
the old module paths still import, with a DeprecationWarning, until 0.3.0).
"""
