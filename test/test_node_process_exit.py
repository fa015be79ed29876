"""A node process ends on SIGINT even when nothing wakes its executor's wait.

Seen once in a fresh clone's suite: a geometry_loader alive 15 s after SIGINT (killed by the test's deadline),
its main thread in the executor's wait, which had no timeout: the signal's wake-up of the wait was lost, and
nothing else came to wake it. ``ros.runtime.spin_node`` now waits at most ``SIGNAL_CHECK_S`` at a time, so the
interpreter raises the pending KeyboardInterrupt between waits. Here rclpy's own signal handlers are left out
altogether and the node is idle when the signal comes, which makes the lost wake-up certain rather than rare.
"""

import os
import signal
import subprocess
import sys
import time

from ros_harness import OutputLines, ros_environment

PROBE = """
import signal
import rclpy
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from edm_planner.ros import runtime

plain_init = rclpy.init
rclpy.init = lambda args=None: plain_init(args=args, signal_handler_options=SignalHandlerOptions.NO)
signal.signal(signal.SIGINT, signal.default_int_handler)   # the interpreter's own: KeyboardInterrupt, pending

class Probe(Node):
    def __init__(self):
        super().__init__("sigint_probe")
        self.timer = self.create_timer(0.2, self.ready)
    def ready(self):
        self.timer.cancel()
        print("spinning", flush=True)

print("exit", runtime.spin_node(Probe), flush=True)
"""


def test_a_node_process_ends_on_a_sigint_that_nothing_wakes_its_executor_for():
    proc = subprocess.Popen([sys.executable, "-c", PROBE], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, env=ros_environment())
    lines = OutputLines(proc)
    try:
        lines.wait_for("spinning", 60)
        time.sleep(1.0)                               # idle: the timer's task done, nothing left to wake the wait
        sent = time.monotonic()
        os.kill(proc.pid, signal.SIGINT)
        proc.wait(timeout=20)
        took = time.monotonic() - sent
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    lines.wait_for("exit 0", 10)
    assert proc.returncode == 0 and took < 5.0, (proc.returncode, took, lines.text)
