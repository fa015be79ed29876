"""Service round-trip benchmarks: nodes in this process, a client over DDS on loopback.

Every figure is the median of ``repeat`` calls after one warm-up call
(numba's first call, DDS discovery and the first reply's allocations are not
timed).
"""

import contextlib
import os
import threading
import time

import numpy as np
import rclpy
from edm_planner_msgs.srv import CheckInterference, LoadGeometry
from rclpy.context import Context
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node

from ..nodes.geometry_loader import GeometryLoaderNode
from ..nodes.interference_checker import InterferenceCheckerNode
from ..ros.conversions import matrix_to_pose
from ..ros.dds import loopback_unless_told


@contextlib.contextmanager
def nodes_in_process():
    """geometry_loader and interference_checker spinning in this process, and a client node.

    Yields (loader, checker, client); pass it as ``nodes`` to the round trips
    below to time several of them on one bring-up.
    """

    loopback_unless_told()
    os.environ.setdefault("ROS_DOMAIN_ID", str(101 - os.getpid() % 50))


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
        if not checker.checkers:
            raise RuntimeError("the interference_checker received no geometry within 120 s")
        yield loader, checker, client
    finally:
        ex.shutdown()
        for node in (loader, checker, client):
            node.destroy_node()
        rclpy.try_shutdown(context=ctx)


def _median_call_ms(client, srv_type, name, request, repeat):
    """Median wall time [ms] of ``repeat`` calls after one untimed call; the last response."""
    cli = client.create_client(srv_type, name)
    if not cli.wait_for_service(timeout_sec=30):
        raise RuntimeError(f"service {name} not available")

    def call():
        fut = cli.call_async(request)
        while not fut.done():
            time.sleep(0.0005)
        return fut.result()

    call()
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        response = call()
        times.append(time.perf_counter() - t)
    return round(1e3 * float(np.median(times)), 1), response


def _bring_up(nodes):
    """``nodes`` as a context (the caller's bring-up), or a bring-up of this call's own."""
    return contextlib.nullcontext(nodes) if nodes is not None else nodes_in_process()


def service_round_trip(n_poses, poses_near, repeat=7, nodes=None):
    """Median round trip [ms] of CheckInterference (fast method) of ``n_poses`` poses near the final pose."""

    with _bring_up(nodes) as (_, checker, client):
        gid, ch = next(iter(checker.checkers.items()))
        ch.fast                                                  # field built before timing
        final = next(iter(ch.electrodes.values()))[1]
        req = CheckInterference.Request(geometry_id=gid, method=CheckInterference.Request.METHOD_FAST)
        req.poses = [matrix_to_pose(p) for p in poses_near(final, n_poses)]
        ms, response = _median_call_ms(client, CheckInterference, "check_interference", req, repeat)
        if response.error_code.val != 0 or len(response.clearances) != n_poses:
            raise RuntimeError(f"CheckInterference failed: {response.message}")
        return ms


def load_geometry_round_trip(path, repeat=7, nodes=None):
    """Median round trip [ms] of LoadGeometry of a file the geometry_loader has loaded already.

    The node loads its default file when it starts; the timed calls name
    the same unchanged file, which it answers from memory by content hash.
    """

    with _bring_up(nodes) as (_, _, client):
        ms, response = _median_call_ms(client, LoadGeometry, "load_geometry", LoadGeometry.Request(path=str(path)),
                                       repeat)
        if not response.success:
            raise RuntimeError(f"LoadGeometry failed: {response.message}")
        return ms
