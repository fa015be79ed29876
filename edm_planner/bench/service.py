"""Service round-trip benchmarks: the nodes and a client over DDS on loopback, in a child process.

The timing itself is a program of the ROS shell, :mod:`edm_planner.nodes.programs.service_bench` (the bench
imports no rclpy and no ROS message, ``.importlinter``): it brings geometry_loader and interference_checker
up in its process, times the calls and prints JSON, which this module reads. Every figure is the median of
``repeat`` calls after one warm-up call (numba's first call, DDS discovery and the first reply's allocations
are not timed).

The child runs with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` and a ROS domain of the bench's own unless
the caller's environment names them, and with a deadline: one that does not finish within it is asked for
its Python stacks (``SIGUSR1``), killed, and reported with the end of its stderr.
"""

import json
import os
import signal
import subprocess
import sys
import tempfile

import numpy as np

#: the program that times the calls (the ROS shell's; ``python -m``)
PROGRAM = "edm_planner.nodes.programs.service_bench"
#: how long one bring-up and its round trips may take [s]: seconds when the field is cached, a minute or two
#: when it is built; beyond it the child is taken as hung
DEADLINE_S = 600
#: how long a hung child has to print its stacks before it is killed [s]
STACKS_WAIT_S = 2
#: how much of the child's stderr a failure shows [characters]
STDERR_TAIL = 6000


def child_environment(environ=None):
    """The child's environment: ours, DDS on this machine and the bench's domain unless ours names them."""
    env = dict(os.environ if environ is None else environ)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    env.setdefault("ROS_DOMAIN_ID", str(101 - os.getpid() % 50))
    return env


def _tail(text):
    text = (text or "").strip()
    return text if len(text) <= STDERR_TAIL else "...\n" + text[-STDERR_TAIL:]


def _kill(proc):
    """SIGKILL the child's process group (its session), if it is still there."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass


def run_json(cmd, env=None, deadline_s=DEADLINE_S):
    """Run ``cmd`` with a deadline; the JSON object of the last line of its stdout.

    Raises
    ------
    RuntimeError
        The child did not finish within ``deadline_s`` (its stacks, asked for with ``SIGUSR1``, and the end of
        its stderr in the message), exited non-zero, or printed no JSON object last.
    """
    what = " ".join(map(str, cmd))
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    try:
        out, err = proc.communicate(timeout=deadline_s)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGUSR1)                  # faulthandler: every thread's stack on stderr
        try:
            proc.communicate(timeout=STACKS_WAIT_S)
        except subprocess.TimeoutExpired:
            pass
        _kill(proc)
        _, err = proc.communicate()
        raise RuntimeError(f"{what} did not finish within {deadline_s} s (hung?); killed. Its stderr:\n"
                           f"{_tail(err)}") from None
    except BaseException:                                 # Ctrl-C: no child left behind
        _kill(proc)
        proc.communicate()
        raise
    if proc.returncode:
        raise RuntimeError(f"{what} exited {proc.returncode}. Its stderr:\n{_tail(err)}")
    lines = [line for line in out.splitlines() if line.strip()]
    try:
        result = json.loads(lines[-1])
        if not isinstance(result, dict):
            raise ValueError("not an object")
    except (IndexError, ValueError) as e:
        raise RuntimeError(f"{what} printed no JSON object last ({e}): stdout {out.strip()[-400:]!r}. "
                           f"Its stderr:\n{_tail(err)}") from None
    return result


def service_round_trips(offsets=None, load_geometry=None, repeat=7, deadline_s=DEADLINE_S):
    """The service round trips asked for, timed on one bring-up of the nodes in a child process.

    Parameters
    ----------
    offsets : (n, 4, 4) array, optional
        CheckInterference (fast method) of n poses: these offsets about the final pose of the checker's first
        electrode (``poses_near(np.eye(4), n)`` gives ``poses_near(final_pose, n)``; see
        :func:`edm_planner.nodes.programs.service_bench.poses_about`).
    load_geometry : str, optional
        LoadGeometry of this file, one the geometry_loader loaded when it started (``"default_blisk.yaml"``).
    repeat : int
        Timed calls per service, after one untimed call.
    deadline_s : float
        How long the child may take, bring-up included.

    Returns
    -------
    dict
        ``check_interference_ms`` (with ``check_interference_poses``) and ``load_geometry_ms`` [ms, medians],
        those asked for.
    """
    cmd = [sys.executable, "-m", PROGRAM, "--repeat", str(repeat)]
    with tempfile.TemporaryDirectory(prefix="edm_bench_service_") as tmp:
        if offsets is not None:
            path = os.path.join(tmp, "offsets.npy")
            np.save(path, np.asarray(offsets, dtype=float))
            cmd += ["--check-poses", path]
        if load_geometry is not None:
            cmd += ["--load-geometry", str(load_geometry)]
        return run_json(cmd, env=child_environment(), deadline_s=deadline_s)


def service_round_trip(n_poses, poses_near, repeat=7, deadline_s=DEADLINE_S):
    """Median round trip [ms] of CheckInterference (fast method) of ``n_poses`` poses near the final pose.

    ``poses_near`` is :func:`edm_planner.bench.common.poses_near`, called as ``poses_near(final_pose, n)``.
    """
    trips = service_round_trips(offsets=poses_near(np.eye(4), n_poses), repeat=repeat, deadline_s=deadline_s)
    return trips["check_interference_ms"]
