"""``make demo``'s and ``make soak``'s bring-up: nodes forked from the preloaded server, over real DDS."""

import os
import signal

import pytest
import rclpy
from edm_planner_msgs.msg import ErrorCode
from edm_planner_msgs.srv import ExecutePlan
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from edm_planner.nodes.programs.bringup import Bringup
from ros_harness import wait_for


def test_a_forked_node_runs_in_the_environment_of_start_answers_stops_and_is_reported_when_killed(tmp_path,
                                                                                                   monkeypatch):
    # the server starts on one domain; the node is started on another and must be found there
    base = int(os.environ["ROS_DOMAIN_ID"])
    server_domain, node_domain = (base + 157) % 232, (base + 171) % 232
    monkeypatch.setenv("ROS_DOMAIN_ID", str(server_domain))
    Bringup.preload(("axis_bridge",))
    monkeypatch.setenv("ROS_DOMAIN_ID", str(node_domain))
    bringup = Bringup(tmp_path / "logs")
    context = Context()
    rclpy.init(context=context, domain_id=node_domain)
    executor = SingleThreadedExecutor(context=context)
    client_node = Node("bringup_client", context=context)
    executor.add_node(client_node)
    try:
        bringup.start(("axis_bridge",))
        bringup.check_alive()
        client = client_node.create_client(ExecutePlan, "execute_plan")
        assert client.wait_for_service(timeout_sec=120), (tmp_path / "logs" / "axis_bridge.log").read_text()
        future = client.call_async(ExecutePlan.Request(plan_id="nothing", dry_run=True))
        executor.spin_until_future_complete(future, timeout_sec=60)
        res = wait_for(future, 1, "ExecutePlan")
        assert res.error_code.val == ErrorCode.UNKNOWN_ID and "nothing" in res.message
        log = (tmp_path / "logs" / "axis_bridge.log").read_text()
        assert "machine 'edm5_reference'" in log, log         # its stdout and stderr are its log
        proc = bringup.procs["axis_bridge"][0]
        bringup.stop()                                        # SIGINT: the node's own clean exit
        assert proc.returncode == 0, log
        assert bringup.procs == {}

        bringup.start(("axis_bridge",))
        proc = bringup.procs["axis_bridge"][0]
        assert client.wait_for_service(timeout_sec=120)       # up again
        os.killpg(proc.pid, signal.SIGKILL)                   # a session of its own: its group is itself
        assert proc.wait(timeout=30) == -signal.SIGKILL
        with pytest.raises(RuntimeError, match="node axis_bridge exited with -9"):
            bringup.check_alive()
    finally:
        bringup.stop()
        executor.shutdown()
        client_node.destroy_node()
        rclpy.try_shutdown(context=context)


def test_the_server_maps_its_modules_to_files_once_for_every_forked_node(monkeypatch):
    """rclpy's logger looks up each call's file with inspect.getframeinfo, whose first call maps every loaded
    module to its file (0.2 s with the nodes' modules): the server does it after the nodes' imports."""
    import subprocess
    import sys

    from edm_planner.nodes.programs import bringup

    preloaded = []
    monkeypatch.setattr(bringup.multiprocessing.forkserver, "set_forkserver_preload", preloaded.extend)
    monkeypatch.setattr(bringup.multiprocessing.forkserver, "ensure_running", lambda: None)
    Bringup.preload(("axis_bridge", "geometry_loader"))
    assert preloaded == [bringup.SERVER_EXIT, "edm_planner.nodes.axis_bridge", "edm_planner.nodes.geometry_loader",
                         bringup.SERVER_WARMUP]
    # in a process of its own, as the server: after the warm-up a log call's lookup maps nothing new
    probe = ("import importlib, inspect, sys\n"
             f"for name in {preloaded!r}: importlib.import_module(name)\n"
             "mapped = len(inspect.modulesbyfile)\n"
             "inspect.getframeinfo(inspect.currentframe())\n"
             "print(len(sys.modules), mapped, len(inspect.modulesbyfile))\n")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=300, check=True)
    modules, mapped, after = map(int, out.stdout.split())
    assert modules > 1000 and mapped > 1000 and after == mapped, out.stdout


def test_the_server_fills_numbas_registries_once_and_starts_no_kernel_threads():
    """numba fills its target's registries on the first kernel a process loads (0.3 s of CPU): the server's
    warm-up does it for every forked node; it runs no kernel, so numba's thread pool starts in the node."""
    import subprocess
    import sys

    from edm_planner.nodes.programs import bringup

    probe = ("import importlib, numpy as np\n"
             "from numba.core.registry import cpu_target\n"
             "from numba.np.ufunc import parallel\n"
             f"for name in {bringup._node_modules(bringup.NODES)!r}: importlib.import_module(name)\n"
             "ctx = cpu_target.target_context\n"
             "before = len(ctx._registries)\n"
             f"importlib.import_module({bringup.SERVER_WARMUP!r})\n"
             "warm, threads = len(ctx._registries), parallel._is_initialized\n"
             "from edm_planner.interference.wall_features import triangle_grid\n"
             "triangle_grid(np.eye(3), np.array([[0, 1, 2]]))\n"        # a kernel of the package, from the cache
             "print(before, warm, len(ctx._registries), threads)\n")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    before, warm, after, threads = out.stdout.split()
    assert int(warm) > int(before) and after == warm and threads == "False", out.stdout


def test_the_bridge_loads_its_timing_solver_while_it_waits_and_the_timing_module_alone_does_not():
    """Every ExecutePlan times with toppra (0.8 s to import, matplotlib with it): the axis bridge imports it in
    a thread of its own once it is up, not in its first request (nor in make demo's fork server, whose imports
    every node waits for); ``cnc.timing`` alone stays light for the programs that never time."""
    import subprocess
    import sys

    probe = ("import sys, rclpy\n"
             "from edm_planner.nodes.axis_bridge import AxisBridgeNode\n"
             "before = 'toppra.algorithm' in sys.modules\n"
             "rclpy.init()\n"
             "node = AxisBridgeNode()\n"
             "assert node.solver_loaded.wait(300)\n"
             "print(before, 'toppra.algorithm' in sys.modules, 'toppra.constraint' in sys.modules)\n"
             "node.destroy_node()\n"
             "rclpy.shutdown()\n")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0 and out.stdout.split() == ["False", "True", "True"], out.stdout + out.stderr
    timing = subprocess.run([sys.executable, "-c", "import sys, edm_planner.cnc.timing; "
                             "print('toppra' in sys.modules)"], capture_output=True, text=True, timeout=300)
    assert timing.stdout.split() == ["False"], timing.stdout + timing.stderr


def test_the_server_runs_every_atexit_handler_then_leaves_without_the_teardown(tmp_path):
    """server_exit, imported before the nodes' modules, registers the handler that runs last: the handlers the
    later imports register still run, the objects' teardown (here a __del__ writing a file) does not."""
    import subprocess
    import sys

    probe = ("import atexit, pathlib, sys\n"
             "import edm_planner.nodes.programs.server_exit\n"
             f"out = pathlib.Path({str(tmp_path)!r})\n"
             "atexit.register(lambda: (out / 'atexit').write_text('ran'))\n"
             "class Teardown:\n"
             "    def __del__(self):\n"
             "        (out / 'teardown').write_text('ran')\n"
             "kept = Teardown()\n"
             "sys.stdout.write('flushed')\n")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and done.stdout == "flushed", done.stderr
    assert (tmp_path / "atexit").exists() and not (tmp_path / "teardown").exists()


def _killed_while(node, other, count):
    """SIGKILL ``node``, then ``count`` threads at once: pollers of it, and (every second one) ``other(seen)``;
    the exit codes they saw (``other`` adds its own to the list it is given)."""
    import threading
    import time

    os.kill(node.pid, signal.SIGKILL)
    start, seen = threading.Barrier(count), []

    def poller():
        start.wait()
        deadline = time.monotonic() + 30
        while (code := node.poll()) is None:
            assert time.monotonic() < deadline, "the killed process was never reported"
        seen.append(code)

    def run_other():
        start.wait()
        other(seen)

    threads = [threading.Thread(target=run_other if i % 2 else poller) for i in range(count)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=60)
    return seen


def test_a_killed_node_process_reports_its_signal_to_every_thread_that_polls_it():
    """multiprocessing reads a forked process's exit status from the fork server's pipe once; threads that poll
    and wait at the same moment must all get SIGKILL's -9 (a second reader once got 255, "the server was
    killed", and make demo's client would have named the wrong cause)."""
    import time

    from edm_planner.nodes.programs.bringup import _CONTEXT, NodeProcess

    for _ in range(12):
        node = NodeProcess.started(_CONTEXT.Process(target=time.sleep, args=(120,), daemon=True))
        assert node.poll() is None
        seen = _killed_while(node, lambda seen: seen.append(node.wait(timeout=30)), 8)
        assert seen == [-signal.SIGKILL] * 8 and node.returncode == -signal.SIGKILL


def test_a_killed_node_process_reports_its_signal_while_other_node_processes_start():
    """``Process.start`` first polls every child of this process (multiprocessing's ``_cleanup``): a start in one
    thread read a killed node's status while another thread polled it, and the poll got 255 ("the server was
    killed") instead of -9 in about one round in eight. ``NodeProcess.started`` starts under the lock the polls
    take."""
    import time

    from edm_planner.nodes.programs.bringup import _CONTEXT, NodeProcess

    def start_others(seen):
        for _ in range(3):
            other = NodeProcess.started(_CONTEXT.Process(target=time.sleep, args=(0,), daemon=True))
            others.append(other.wait(timeout=30))

    for _ in range(40):
        node = NodeProcess.started(_CONTEXT.Process(target=time.sleep, args=(120,), daemon=True))
        others = []
        seen = _killed_while(node, start_others, 6)
        assert seen == [-signal.SIGKILL] * 3 and node.returncode == -signal.SIGKILL
        assert others == [0] * 9
