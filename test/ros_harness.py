"""Launch-free test harness: our nodes in-process or as OS processes, over real DDS.

In-process: a private rclpy ``Context``, the nodes and a
``MultiThreadedExecutor`` spinning in a thread (after rclpy's and
tf2_ros_py's own tests). Processes: the nodes' console entry points from
``.venv/bin``. Both keep DDS on loopback and on the test run's own domain.
"""

import os
import pathlib
import signal
import subprocess
import sys
import threading
import time

import rclpy
from rclpy.context import Context
from rclpy.executors import MultiThreadedExecutor

VENV_BIN = pathlib.Path(sys.prefix) / "bin"


def ros_environment():
    """Environment for ROS processes of this test run (loopback DDS, own domain)."""
    env = dict(os.environ)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.setdefault("ROS_DOMAIN_ID", os.environ["ROS_DOMAIN_ID"])
    env["AMENT_PREFIX_PATH"] = sys.prefix
    env["PYTHONUNBUFFERED"] = "1"
    return env


class InProcessRos:
    """Nodes on a private context with an executor thread; use as a context manager."""

    def __init__(self):
        self.context = Context()
        rclpy.init(context=self.context)
        self.executor = MultiThreadedExecutor(num_threads=4, context=self.context)
        self.nodes = []
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self):
        try:
            self.executor.spin()
        except Exception:  # executor shut down while spinning
            pass

    def add(self, node):
        """Add a node (created with ``context=self.context``) to the executor."""
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def call(self, client_node, srv_type, name, request, timeout=30.0):
        """Call a service over DDS from ``client_node`` and return its response."""
        client = client_node.create_client(srv_type, name)
        try:
            if not client.wait_for_service(timeout_sec=timeout):
                raise TimeoutError(f"service {name} not available after {timeout} s")
            future = client.call_async(request)
            deadline = time.monotonic() + timeout
            while not future.done():
                if time.monotonic() > deadline:
                    raise TimeoutError(f"service {name} did not answer within {timeout} s")
                time.sleep(0.01)
            return future.result()
        finally:
            client_node.destroy_client(client)

    def close(self):
        self.executor.shutdown(timeout_sec=5.0)
        self._thread.join(timeout=5.0)
        for node in self.nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=self.context)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class NodeProcesses:
    """Our nodes as separate OS processes through their console entry points."""

    def __init__(self, log_dir):
        self.log_dir = pathlib.Path(log_dir)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.procs = {}

    def start(self, executable, *args, params=None):
        """Start ``.venv/bin/<executable>`` with ``--ros-args -p k:=v`` parameters."""
        cmd = [str(VENV_BIN / executable), *args]
        if params:
            cmd += ["--ros-args"] + [x for k, v in params.items() for x in ("-p", f"{k}:={v}")]
        log = open(self.log_dir / f"{executable}.log", "a")     # a restarted node appends
        self.procs[executable] = (subprocess.Popen(
            cmd, env=ros_environment(), stdout=log, stderr=subprocess.STDOUT,
            start_new_session=True), log)
        return self.procs[executable][0]

    def log(self, executable):
        return (self.log_dir / f"{executable}.log").read_text()

    def stop(self, *names):
        """Stop the named processes (all without names); returns their exit codes by name."""
        names = names or tuple(self.procs)
        for name in names:
            proc = self.procs[name][0]
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for name in names:
            proc, log = self.procs[name]
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
            log.close()
        return {name: self.procs[name][0].returncode for name in names}
