"""A new user's shell on the ROS 2 underlay: ``tools/ros_underlay.bash`` (for ``source /opt/ros/jazzy/setup.bash``).

Used by the tests that build as a ROS 2 user would: a colcon workspace (``test_colcon_workspace``) and a C++
program against the interfaces (``test_cpp_typesupport``).
"""

import os
import shlex
import subprocess
import sys

from conftest import REPO
from ros_harness import ros_environment

UNDERLAY = REPO / "tools" / "ros_underlay.bash"


def user_environment():
    """A new shell's environment: nothing of this process's ROS, Python or library set-up, DDS kept local."""
    env = ros_environment()         # loopback DDS, this run's domain, unbuffered output
    for name in ("AMENT_PREFIX_PATH", "CMAKE_PREFIX_PATH", "COLCON_PREFIX_PATH", "PYTHONPATH", "LD_LIBRARY_PATH",
                 "VIRTUAL_ENV", "_ROS_WHEELS_BOOTSTRAP_COMPLETE", "PYTHONHOME"):
        env.pop(name, None)
    venv_bin = os.path.join(sys.prefix, "bin")
    env["PATH"] = os.pathsep.join(p for p in env.get("PATH", "/usr/bin:/bin").split(os.pathsep) if p != venv_bin)
    return env


def shell_command(ws, script, overlay=True):
    """``bash -c``: the underlay, the workspace's install/setup.bash (if ``overlay``), then ``script``."""
    steps = [f"source {shlex.quote(str(UNDERLAY))} {shlex.quote(sys.prefix)}", f"cd {shlex.quote(str(ws))}"]
    if overlay:
        steps.append("source install/setup.bash")
    return ["bash", "-c", " && ".join(steps + [script])]


def run_in_shell(ws, script, overlay=True, timeout=120, env=None, stdin=None):
    """``shell_command`` run to its end (``timeout`` s): the CompletedProcess, output as text."""
    return subprocess.run(shell_command(ws, script, overlay), env=env or user_environment(), input=stdin,
                          capture_output=True, text=True, timeout=timeout)
