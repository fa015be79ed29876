"""Running a node as a process: the shared body of every console entry point."""

import faulthandler
import logging
import os
import signal
import time

import rclpy
from ament_index_python.packages import PackageNotFoundError, get_package_share_directory
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor

from ..errors import EdmError, ErrorCode
from ..cnc.config import default_machine_path
from ..records.store import PlanStoreError, open_store
from .conversions import error_code


#: threads of a node process's executor
EXECUTOR_THREADS = 8

#: the longest a node process's executor waits in DDS at a time [s]: how soon it sees a SIGINT whose wake-up
#: of the wait was lost (then only the interpreter's own check of pending signals, between waits, sees it)
SIGNAL_CHECK_S = 0.25


def spin_node(node_class, args=None):
    """Init rclpy, spin one node on a MultiThreadedExecutor until Ctrl-C or shutdown, clean up.

    Returns
    -------
    int
        The process exit code (0).
    """
    logging.basicConfig(level=logging.INFO, format="[%(name)s] %(levelname)s: %(message)s")
    enable_stack_dumps()
    rclpy.init(args=args)
    node = node_class()
    # threads enough that long work (a set design, a followed trajectory, a plan) never holds up a cancel, the
    # latched geometry or a short service call behind it (the default is one thread per core: 2 here)
    executor = MultiThreadedExecutor(num_threads=EXECUTOR_THREADS)
    executor.add_node(node)
    try:
        # not executor.spin(): its wait has no timeout, and rclpy's SIGINT handler now and then fails to wake
        # it (seen: a loader alive 15 s after SIGINT, its main thread in the wait); a finite wait returns to
        # the interpreter, which raises the KeyboardInterrupt the signal left pending
        while executor.context.ok():
            executor.spin_once(timeout_sec=SIGNAL_CHECK_S)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


def enable_stack_dumps():
    """``kill -USR1 <pid>`` prints every thread's Python stack to stderr (the node's log), even while the process
    is stuck in C code (a DDS call): what a supervisor or a test's deadline reports of a node that does not answer."""
    faulthandler.register(signal.SIGUSR1, all_threads=True)


def end_canceled(goal_handle, timeout=10.0):
    """End an action goal CANCELED once rclpy has moved it to CANCELING; True if it did.

    rclpy makes that transition only after the cancel callback has returned, and work stopped by the callback
    (a set design, a followed trajectory) can get here first: CANCELED from EXECUTING is refused
    (``invalid transition``) and the goal would end ABORTED. So wait for the transition, not for ever: a goal
    whose cancel never arrives within ``timeout`` [s] is aborted.
    """
    deadline = time.monotonic() + timeout
    while not goal_handle.is_cancel_requested:
        if time.monotonic() > deadline:
            goal_handle.abort()
            return False
        time.sleep(0.005)
    goal_handle.canceled()
    return True


def answer(node, service, fill, request, response):
    """Serve one request: ``fill(request, response)``, with every failure mapped onto the response.

    An ``EdmError`` becomes its error code and message (logged as a warning), anything else
    INTERNAL with the exception (logged with its traceback); a response with a ``success``
    field gets ``False`` then. ``fill`` sets the error code of the requests it answers itself.
    """
    try:
        fill(request, response)
        return response
    except EdmError as exc:
        code, message = exc.code, exc.message
        node.get_logger().warning(f"{service} refused ({code.name}): {message}")
    except Exception as exc:
        logging.getLogger(node.get_name()).exception(f"{service}: internal error")
        code, message = ErrorCode.INTERNAL, f"internal error: {exc!r}"
    if hasattr(response, "success"):
        response.success = False
    response.error_code = error_code(code)
    response.message = message
    return response


def declare_plan_store(node):
    """Declare the ``plan_store`` parameter and open the store: (store or None, why it is not used).

    A store that cannot be used (foreign, corrupt, unwritable) is logged and left alone; the node
    works without it and names the reason in its answers.
    """
    node.declare_parameter("plan_store", "")
    try:
        return open_store(node.get_parameter("plan_store").value), ""
    except PlanStoreError as exc:
        node.get_logger().error(f"plan store not used: {exc.message}")
        return None, exc.message


def default_machine_file():
    """The machine YAML the nodes use when none is named: the installed share directory's, else the source
    tree's (the axis bridge times on it, the planner plans the process with it: the same file)."""
    try:
        path = os.path.join(get_package_share_directory("edm_planner"), "config", "machine.yaml")
        if os.path.exists(path):
            return path
    except PackageNotFoundError:  # not installed in an ament prefix: the source tree's config
        pass
    return str(default_machine_path())
