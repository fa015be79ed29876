"""Running a node as a process: the shared body of every console entry point."""

import logging

import rclpy
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor


def spin_node(node_class, args=None):
    """Init rclpy, spin one node on a MultiThreadedExecutor until Ctrl-C or shutdown, clean up.

    Returns
    -------
    int
        The process exit code (0).
    """
    logging.basicConfig(level=logging.INFO, format="[%(name)s] %(levelname)s: %(message)s")
    rclpy.init(args=args)
    node = node_class()
    executor = MultiThreadedExecutor()
    executor.add_node(node)
    try:
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
