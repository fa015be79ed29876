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

import queue

import rclpy
from hang_report import register
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


def wait_for(future, timeout, what):
    """The future's result, or TimeoutError naming ``what`` after ``timeout`` seconds (a service's or an action's)."""
    deadline = time.monotonic() + timeout
    while not future.done():
        if time.monotonic() > deadline:
            raise TimeoutError(f"{what}: no answer within {timeout:.0f} s")
        time.sleep(0.01)
    return future.result()


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
            return wait_for(client.call_async(request), timeout, f"service {name}")
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
        path = self.log_dir / f"{executable}.log"
        log = open(path, "a")     # a restarted node appends
        self.procs[executable] = (register(subprocess.Popen(
            cmd, env=ros_environment(), stdout=log, stderr=subprocess.STDOUT,
            start_new_session=True), executable, path), log)
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
                # its threads' stacks into its log first (the nodes dump them on SIGUSR1): what held it up
                os.kill(proc.pid, signal.SIGUSR1)
                time.sleep(1.0)
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
            log.close()
        return {name: self.procs[name][0].returncode for name in names}


class OutputLines:
    """A child's output read line by line in a thread, so that every wait on it has a deadline.

    ``for line in proc.stdout`` blocks for ever when the child prints nothing; :meth:`wait_for` gives up at its
    deadline with what was read so far.
    """

    def __init__(self, proc):
        self.proc, self.lines, self._queue = proc, [], queue.Queue()
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self):
        for line in self.proc.stdout:
            self._queue.put(line)
        self._queue.put(None)

    def _take(self, timeout):
        try:
            line = self._queue.get(timeout=timeout)
        except queue.Empty:
            return False
        if line is None:
            self._queue.put(None)          # the end stays visible to later waits
            return None
        self.lines.append(line)
        return True

    def wait_for(self, text, timeout):
        """Read until a line containing ``text``; TimeoutError (with the output so far) at the deadline or the end."""
        deadline = time.monotonic() + timeout
        while not any(text in line for line in self.lines):
            left = deadline - time.monotonic()
            got = self._take(max(left, 0.0)) if left > 0 else False
            if got is None:
                raise TimeoutError(f"the output ended (exit {self.proc.poll()}) without {text!r}:\n{self.text}")
            if got is False:
                raise TimeoutError(f"no {text!r} within {timeout:g} s; output so far:\n{self.text}")
        return self.text

    def rest(self, timeout):
        """Everything until the end of the output; TimeoutError at the deadline."""
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            got = self._take(left) if left > 0 else False
            if got is None:
                return self.text
            if got is False:
                raise TimeoutError(f"the output did not end within {timeout:g} s; so far:\n{self.text}")

    @property
    def text(self):
        return "".join(self.lines)
