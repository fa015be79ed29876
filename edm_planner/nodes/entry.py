"""The nodes' console scripts (``setup.py``, what ``ros2 run`` and ``ros2 launch`` start): each node's ``main``,
then the process ends without Python's final teardown of rclpy, numba and the core
(:func:`edm_planner.quick_exit.exit_now`; 0.7 to 0.9 s from SIGINT to exit before, AMD Zen 3). The nodes forked by
:mod:`.programs.bringup` call ``main`` themselves and end as a forked process does.
"""

import importlib

from ..quick_exit import exit_now
from ..ros.startup import prepare_process


def _run(name):
    prepare_process()           # before the node's module imports the messages and numpy (OpenBLAS reads it)
    exit_now(importlib.import_module(f"{__package__}.{name}").main())


def geometry_loader():
    _run("geometry_loader")


def interference_checker():
    _run("interference_checker")


def trajectory_planner():
    _run("trajectory_planner")


def axis_bridge():
    _run("axis_bridge")
