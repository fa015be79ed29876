"""Bringing the four nodes up as OS processes.

Each node is its own OS process with its own DDS participant, as ``ros2 launch`` starts them, but forked from
one preloaded server (:mod:`multiprocessing`'s forkserver) rather than started from its console script: the
server imports the nodes' modules once (rclpy, numpy, SciPy, trimesh, numba and the core: about 3 s of CPU
per process here) and every node starts from a copy of it. With four nodes on two cores, separate imports
cost about 4 s of wall time at every bring-up (``make demo``, ``make soak``). The server only imports:
no Python thread, OpenMP pool, rclpy context or DDS participant exists when it forks. The native threads
the imports start are OpenBLAS's (which it shuts down and re-creates around a fork) and the two listener
threads of LTTng-UST (ros2_tracing, loaded with rclpy): a forked node has none, so it cannot be traced
with LTTng; a node started from its console script (``ros2 launch``) can.

This module is light on purpose (no numpy, no messages, no core), so that a program can start the server
first and import its own modules while the server imports the nodes'.
"""

import atexit
import importlib
import multiprocessing
import multiprocessing.connection
import multiprocessing.forkserver
import os
import pathlib
import signal
import subprocess
import sys
import threading

from ...ros.shared import config_directory

NODES = ("geometry_loader", "interference_checker", "trajectory_planner", "axis_bridge")

_CONTEXT = multiprocessing.get_context("forkserver")

#: imported by the server after the nodes' modules: what every process would do once (see the module)
SERVER_WARMUP = "edm_planner.nodes.programs.server_warmup"
#: imported by the server before them: its exit without the teardown of their modules (see the module)
SERVER_EXIT = "edm_planner.nodes.programs.server_exit"


def _node_modules(names):
    return [f"edm_planner.nodes.{name}" for name in names]


def _run_node(name, argv, environ, log_path):
    """A forked node's process: its log as stdout and stderr, a session of its own, the caller's environment,
    then the node's console entry point with ``argv``."""
    fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)
    os.setsid()                       # its own process group: Ctrl-C reaches the program, which stops the nodes
    os.environ.clear()
    os.environ.update(environ)        # as at start(), not as when the server started
    from ...ros.startup import prepare_process
    prepare_process()                 # numba's configuration read again from that environment
    sys.argv = [name] + list(argv)
    raise SystemExit(importlib.import_module(_node_modules([name])[0]).main())


#: held while a forked process's exit status may be read from the server's pipe: by ``NodeProcess.poll``, and by
#: ``Process.start``, which first polls every child the process started (multiprocessing's ``_cleanup``)
_STATUS_LOCK = threading.Lock()


class NodeProcess:
    """A node forked by the server: the part of :class:`subprocess.Popen` that programs and tests use.

    Safe to poll and wait on from several threads (a program's call loop checks its nodes while another
    thread waits for one, or starts a node again): multiprocessing reads a forked process's exit status from
    the server's pipe once, and a second thread reading at the same moment found the pipe empty and took it
    for a killed server, exit code 255 instead of -9 (seen once in ``test_faults``). The second reader may be
    any ``Process.start`` of this process (it polls every child first), so start processes with
    :meth:`started`: polls and starts read the statuses one at a time.
    """

    def __init__(self, process):
        self._process = process
        self._lock = _STATUS_LOCK

    @classmethod
    def started(cls, process):
        """Start a multiprocessing ``process`` of the server (status reads locked, see the class) and wrap it."""
        with _STATUS_LOCK:
            process.start()
        return cls(process)

    @property
    def pid(self):
        return self._process.pid

    @property
    def returncode(self):
        """The exit code, minus the signal that ended it, or None while it runs (as ``Popen.returncode``)."""
        return self.poll()

    def poll(self):
        with self._lock:
            code = self._process.exitcode
            if code is not None:
                self._process.join(0)   # the status is read: only multiprocessing's list of children is left
            return code

    def wait(self, timeout=None):
        # wait for the status without reading it (any thread may), then read it under the lock
        multiprocessing.connection.wait([self._process.sentinel], timeout)
        code = self.poll()
        if code is None:
            raise subprocess.TimeoutExpired(self._process.name, timeout)
        return code

    def send_signal(self, sig):
        try:
            os.kill(self.pid, sig)
        except ProcessLookupError:    # ended since the caller looked
            pass


class Bringup:
    """The nodes as OS processes forked from the preloaded server; each node's log in ``log_dir``."""

    def __init__(self, log_dir, params=None):
        self.log_dir = pathlib.Path(log_dir)
        self.log_dir.mkdir(parents=True, exist_ok=True)
        self.params = params or {}
        self.procs = {}
        # before multiprocessing's own exit handler, which would wait for nodes still running
        atexit.register(self.stop)

    @staticmethod
    def preload(names=NODES):
        """Start the server importing the nodes' modules, and return at once (``start`` waits for it).

        The server is one per process and keeps the modules of the first call; a later start of other nodes
        imports theirs in the node's own process.
        """
        multiprocessing.forkserver.set_forkserver_preload([SERVER_EXIT] + _node_modules(names) + [SERVER_WARMUP])
        multiprocessing.forkserver.ensure_running()

    def start(self, names=NODES):
        self.preload(names)
        for name in names:
            # the cell's parameters file (what launch/edm_cell.launch.py passes), then the program's own
            argv = ["--ros-args", "--params-file", str(config_directory() / "edm_cell.yaml")]
            argv += [x for k, v in self.params.get(name, {}).items() for x in ("-p", f"{k}:={v}")]
            process = _CONTEXT.Process(target=_run_node, name=name, daemon=False,
                                       args=(name, argv, dict(os.environ), str(self.log_dir / f"{name}.log")))
            self.procs[name] = (NodeProcess.started(process), None)

    def check_alive(self):
        for name, (proc, _) in self.procs.items():
            if proc.poll() is not None:
                raise RuntimeError(f"node {name} exited with {proc.returncode}; see {self.log_dir / name}.log")

    def stop(self):
        for proc, _ in self.procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        for proc, _ in self.procs.values():
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                try:
                    os.killpg(proc.pid, signal.SIGKILL)
                except ProcessLookupError:        # not yet in a session of its own
                    proc.send_signal(signal.SIGKILL)
                proc.wait()
        self.procs = {}
