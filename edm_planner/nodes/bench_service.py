"""The service round-trip benchmark: nodes in this process, a client over DDS on loopback."""

import time

import numpy as np


def service_round_trip(n_poses, poses_near, repeat=5):
    """Median round trip of CheckInterference (fast method) over DDS, nodes in this process."""
    import os
    import threading

    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ.setdefault("ROS_DOMAIN_ID", str(101 - os.getpid() % 50))
    import rclpy
    from edm_planner_msgs.srv import CheckInterference
    from rclpy.context import Context
    from rclpy.executors import MultiThreadedExecutor
    from rclpy.node import Node

    from .conversions import matrix_to_pose
    from .geometry_loader import GeometryLoaderNode
    from .interference_checker import InterferenceCheckerNode

    ctx = Context()
    rclpy.init(context=ctx)
    ex = MultiThreadedExecutor(context=ctx)
    loader = GeometryLoaderNode(context=ctx)
    checker = InterferenceCheckerNode(context=ctx)
    client = Node("bench_client", context=ctx)
    for node in (loader, checker, client):
        ex.add_node(node)
    th = threading.Thread(target=ex.spin, daemon=True)
    th.start()
    try:
        deadline = time.monotonic() + 120
        while not checker.checkers and time.monotonic() < deadline:
            time.sleep(0.1)
        gid, ch = next(iter(checker.checkers.items()))
        ch.fast                                                  # field built before timing
        final = next(iter(ch.electrodes.values()))[1]
        req = CheckInterference.Request(geometry_id=gid, method=CheckInterference.Request.METHOD_FAST)
        req.poses = [matrix_to_pose(p) for p in poses_near(final, n_poses)]
        cli = client.create_client(CheckInterference, "check_interference")
        cli.wait_for_service(timeout_sec=30)
        times = []
        for _ in range(repeat):
            t = time.perf_counter()
            fut = cli.call_async(req)
            while not fut.done():
                time.sleep(0.0005)
            times.append(time.perf_counter() - t)
        return round(1e3 * float(np.median(times)), 1)
    finally:
        ex.shutdown()
        for node in (loader, checker, client):
            node.destroy_node()
        rclpy.try_shutdown(context=ctx)
