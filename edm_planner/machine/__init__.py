"""Deprecated package: the machine tool's code (kinematics, the machine file, timing, trajectories, NC) is
:mod:`edm_planner.cnc` since issue 27 (``machine`` and ``machining`` were nearly the same word). Its modules
still import from here, each name with a DeprecationWarning, until release 0.3.0
(:mod:`edm_planner.deprecation`)."""
